"""Reliability sweep 2 as regression tests: every message true, sizes checked before work.

Each case gives exit 2 and one line on stderr naming what the user gave (or the right result),
writes nothing, and where a computation would follow, is refused before it starts. The cases are
those a hostile-but-realistic user met (issue 23), plus neighbours of each.
"""

import json

import numpy as np
import pytest

from piest_jax._cli import compensate as compensate_cmd
from piest_jax._cli import fit as fit_cmd
from piest_jax._cli import main, memory
from piest_jax._cli import montecarlo as montecarlo_cmd
from piest_jax._cli import simulate as simulate_cmd
from piest_jax._diagnosis import diagnose as _diagnose
from piest_jax._estimation import online as _online
from piest_jax._identification import model_file

T = 0.01 * np.arange(300)
U = 2 * np.sin(2 * np.pi * T)
Y = 0.5 * U + 0.1 * np.cos(2 * np.pi * T)
MODEL = {"thresholds": [0.0, 0.5], "weights": [1.0, 0.5], "offset": 0.1, "initial_states": [0.0, 0.0]}


class _Started(BaseException):
    """A computation started although the request should have been refused first."""


def _started(*args, **kwargs):
    raise _Started


# Where each command's computation starts.
_STARTS = [
    (fit_cmd, "identify"),
    (_diagnose, "diagnose"),
    (compensate_cmd, "feedforward"),
    (montecarlo_cmd, "pe_map"),
    (_online, "estimate_record"),
    (simulate_cmd.PIOperator, "regressor"),
]


@pytest.fixture
def files(tmp_path):
    rec = tmp_path / "rec.csv"
    rec.write_text("t,u,y\n" + "".join(f"{a!r},{b!r},{c!r}\n" for a, b, c in zip(T.tolist(), U.tolist(), Y.tolist())))
    gap = tmp_path / "gap.csv"
    tg = np.where(T > 1, T + 0.5, T)
    gap.write_text("t,u,y\n" + "".join(f"{a!r},{b!r},{c!r}\n" for a, b, c in zip(tg.tolist(), U.tolist(), Y.tolist())))
    model = tmp_path / "model.json"
    model.write_text(json.dumps(MODEL))
    seg = tmp_path / "seg.csv"
    seg.write_text(
        "segment,t,u,y\n"
        + "".join(
            f"{k // 100},{a!r},{b!r},{c!r}\n"
            for k, (a, b, c) in enumerate(zip((T % 1).tolist(), U.tolist(), Y.tolist()))
        )
    )
    short = tmp_path / "short.csv"
    short.write_text("segment,t,u,y\n" + "".join(f"{int(k >= 20)},{k},{k % 7},{k % 5}\n" for k in range(25)))
    return {
        "rec": str(rec),
        "gap": str(gap),
        "model": str(model),
        "seg": str(seg),
        "short": str(short),
        "dir": tmp_path,
    }


def _run(capsys, argv, *, stop=True):
    with pytest.MonkeyPatch.context() as mp:
        if stop:
            for owner, attr in _STARTS:
                mp.setattr(owner, attr, _started)
        try:
            code = main(argv)
        except SystemExit as e:
            code = e.code
    cap = capsys.readouterr()
    return code, cap.out, cap.err


def _refused(capsys, argv, needle, out):
    code, o, err = _run(capsys, [*argv, "--out", str(out)])
    assert (code, o) == (2, ""), err
    assert err.count("\n") == 1 and err.startswith("piest") and "Traceback" not in err, err
    assert needle in err, (needle, err)
    assert not out.exists() or not any(out.iterdir())


# (argv with {rec}, {gap}, {model} placeholders, what the message must say)
CASES = [
    # options a mode ignores
    (
        ["fit", "{rec}", "--plays", "2", "--candidates", "3,4", "--criterion", "bic"],
        "--candidates is used only by --plays auto; --plays 2 fixes the number of plays",
    ),
    (["fit", "{rec}", "--plays", "2", "--criterion", "holdout"], "--criterion is used only by --plays auto"),
    (["fit", "{rec}", "--model", "pi", "--lags", "2"], "--lags needs --model pi+creep or auto"),
    (["fit", "{rec}", "--lags", "2", "--time-constants", "0.5"], "give either --lags or --time-constants"),
    (
        ["estimate", "{rec}", "--estimator", "gradient", "--P0", "5"],
        "--P0 is a setting of --estimator rls or forgetting, not of --estimator gradient",
    ),
    (["estimate", "{rec}", "--gain", "2"], "--gain is a setting of --estimator gradient, not of --estimator rls"),
    (["estimate", "{rec}", "--forgetting", "0.9"], "--forgetting is a setting of --estimator forgetting"),
    (
        ["estimate", "{rec}", "--estimator", "forgetting", "--normalisation", "standard"],
        "--normalisation is a setting of --estimator rls",
    ),
    (["simulate", "--columns", "a,b,c"], "--columns is only used with --input csv"),
    (
        ["simulate", "--input", "csv", "--csv", "{rec}", "--amplitude", "3"],
        "--amplitude describes a generated input; --input csv takes t and u from {rec}",
    ),
    (["simulate", "--input", "csv", "--csv", "{rec}", "--dt", "0.5"], "--dt describes a generated input"),
    # non-finite values named at parse time, before any fit
    (["fit", "{rec}", "--initial-states", "nan"], "argument --initial-states: must be a finite number, got nan"),
    (["fit", "{rec}", "--fit-from", "inf"], "argument --fit-from: must be a finite number, got inf"),
    (
        ["compensate", "{model}", "{rec}", "--initial-states", "nan"],
        "argument --initial-states: must be a finite number, got nan",
    ),
    (["simulate", "--offset", "nan"], "argument --offset: must be a finite number"),
    # degenerate signals
    (["simulate", "--frequency", "0"], "--frequency 0 Hz: a frequency must be positive (0 Hz gives a constant input"),
    (["simulate", "--frequency=-2"], "--frequency -2 Hz: a frequency must be positive"),
    (
        ["simulate", "--frequency", "500"],
        "--frequency 500 Hz is at or above the Nyquist frequency 500 Hz of --dt 0.001",
    ),
    (["simulate", "--frequency", "1000"], "at or above the Nyquist frequency"),
    (["simulate", "--input", "triangle", "--frequency", "5", "--dt", "0.1"], "--frequency 5 Hz is at or above"),
    (["simulate", "--input", "multisine", "--amplitude", "1,2", "--frequency", "3,600"], "--frequency 600 Hz"),
    (["simulate", "--input", "chirp", "--frequency", "800"], "--frequency 800 Hz"),
    # seeds and counts out of range, at parse time
    (
        ["fit", "{rec}", "--seed", "99999999999999999999999"],
        "argument --seed: a seed is a whole number from 0 to 2^63 - 1",
    ),
    (["montecarlo", "--seed", "99999999999999999999999"], "argument --seed: a seed is a whole number"),
    (["montecarlo", "--seed", "-1"], "argument --seed: a seed is a whole number"),
    (["fit", "{rec}", "--starts", "1_000"], "argument --starts: expected a whole number, got '1_000'"),
    (["montecarlo", "--inputs", "99999999999"], "argument --inputs: must be at most 2147483647"),
    (["montecarlo", "--samples", "\u0661\u0662"], "argument --samples: expected a whole number"),
    # sizes checked before the work
    (
        ["fit", "{rec}", "--starts", "1000000"],
        "--starts 1000000 on {rec} (300 samples, up to 40 parameters) needs about",
    ),
    (["montecarlo", "--samples", "1000000000"], "--samples 1000000000 with --plays 10 needs about"),
    (["montecarlo", "--plays", "100000"], "--samples 5000 with --plays 100000 needs about"),
    (["estimate", "{rec}", "--plays", "100000"], "100001 weights (100000 plays) on {rec} needs about"),
    # a record with a gap: the option named exists for the command
    (["simulate", "--input", "csv", "--csv", "{gap}"], "(CLI: --resample)"),
    (["diagnose", "{gap}"], "(CLI: --resample)"),
    (["fit", "{rec}", "--max-gap", "1"], "--max-gap is only used with --resample"),
    (["simulate", "--max-gap", "1"], "--max-gap is only used with --input csv"),
    (["estimate", "{gap}"], "(CLI: --resample)"),
    # a record of several segments: one of them, when asked for, must hold a record's minimum
    (["fit", "{short}", "--segment", "1"], "{short}: segment 1 has only 5 samples; at least 8 are needed"),
    (["fit", "{seg}", "--segment", "5"], "{seg}: no segment labelled 5; the labels are 0, 1, 2"),
    (["fit", "{rec}", "--segment", "0"], "{rec}: no `segment` column to select segment 0 from"),
    (["simulate", "--segment", "1"], "--segment is only used with --input csv"),
    (["fit", "{seg}", "--segment", "nan"], "argument --segment: must be a finite number"),
]


@pytest.mark.parametrize("argv, needle", CASES, ids=[" ".join(c[0])[:60] for c in CASES])
def test_each_case_is_refused_in_one_line(argv, needle, files, capsys):
    argv = [a.format(**files) for a in argv]
    _refused(capsys, argv, needle.format(**files), files["dir"] / "o")


@pytest.mark.parametrize(
    "command", ["simulate", "fit", "diagnose", "compensate", "estimate", "montecarlo", "reproduce"]
)
def test_an_empty_out_is_refused(command, files, capsys):
    first = {"simulate": [], "montecarlo": [], "reproduce": ["fig5"], "compensate": [files["model"], files["rec"]]}
    argv = [command, *first.get(command, [files["rec"]])]
    code, o, err = _run(capsys, [*argv, "--out", ""])
    assert (code, o) == (2, "") and "argument --out: expected a folder name, got an empty one" in err, err


def test_an_unwritable_out_is_found_before_the_computation(files, capsys):
    # /proc/self is a folder that no one, root included, can create files in.
    code, o, err = _run(capsys, ["fit", files["rec"], "--out", "/proc/self"])
    assert (code, o) == (2, "") and err.startswith(
        "piest fit: error: --out /proc/self: cannot write there (it takes no new files)"
    ), err
    assert ".tmp" not in err


def test_a_gap_is_resampled_where_the_message_says(files, capsys):
    out = files["dir"] / "o"
    # A gap of 51 steps: refused by default (it would invent 50 samples), filled when allowed.
    argv = ["simulate", "--input", "csv", "--csv", files["gap"], "--resample", "--out", str(out)]
    code, _, err = _run(capsys, argv, stop=False)
    assert code == 2 and err.count("\n") == 1, err
    assert "a gap of 0.51 (t = 1 to 1.51) is too long to resample across: longer than 10 median steps" in err
    assert "50 invented samples" in err and "--max-gap" in err and not out.exists()
    code, _, err = _run(capsys, [*argv, "--max-gap", "0.6"], stop=False)
    assert code == 0, err
    data = np.loadtxt(out / "simulate.csv", delimiter=",", skiprows=1)
    np.testing.assert_allclose(np.diff(data[:, 0]), 0.01, rtol=1e-9)


@pytest.mark.parametrize(
    "text, needle",
    [
        (json.dumps(MODEL | {"weights": [True, 0.5]}), "`weights` holds true or false; it must be numbers"),
        (json.dumps(MODEL | {"offset": False}), "`offset` holds true or false"),
        (json.dumps(MODEL | {"thresholds": [0, True]}), "`thresholds` holds true or false"),
        (json.dumps(MODEL).replace('"offset": 0.1', '"offset": ' + "9" * 400), "must be finite"),
        ("[" * 100_000 + "]" * 100_000, "not a model file (nested too deeply)"),
        (
            json.dumps(
                MODEL | {"structure": "pi+creep", "creep": {"time_constants": [1.0], "weights": [True], "dt": 0.01}}
            ),
            "creep: `weights` holds true or false",
        ),
    ],
)
def test_model_files_are_read_with_limits(text, needle, files, capsys):
    model = files["dir"] / "bad.json"
    model.write_text(text)
    _refused(capsys, ["compensate", str(model), files["rec"]], f"{model}: ", files["dir"] / "o")
    _refused(capsys, ["compensate", str(model), files["rec"]], needle, files["dir"] / "o")


def test_a_model_file_too_large_is_refused_unread(files, monkeypatch):
    monkeypatch.setattr(model_file, "MAX_JSON_BYTES", 50)
    with pytest.raises(ValueError, match=r"more than a model file holds"):
        model_file.load_model(files["model"])


def test_estimate_from_fit_refuses_booleans(files, capsys):
    fit = files["dir"] / "fit.json"
    fit.write_text(json.dumps({"thresholds": [0.0, True], "weights": [1.0, 1.0]}))
    _refused(
        capsys,
        ["estimate", files["rec"], "--from-fit", str(fit)],
        "`thresholds` holds true or false",
        files["dir"] / "o",
    )


@pytest.mark.parametrize(
    "content, needle",
    [
        # `piest estimate --from-fit` reads model files as every command does, naming the key.
        ({"schema": 2, "structure": "pi"}, "schema 2 is newer"),
        ({"schema": 1, "structure": "neural", "thresholds": [0.0]}, "unknown model structure 'neural'"),
        ({"schema": 1, "structure": "pi", "thresholds": [0.0, 1.0]}, "missing weights, offset, initial_states"),
        (MODEL | {"thresholds": [0.5, 0.0]}, "`thresholds` must be strictly increasing"),
        (MODEL | {"weights": [1.0, "x"]}, "must be numbers"),
    ],
)
def test_estimate_from_fit_reads_the_model_file(files, capsys, content, needle):
    fit = files["dir"] / "fit.json"
    fit.write_text(json.dumps(content))
    _refused(capsys, ["estimate", files["rec"], "--from-fit", str(fit)], needle, files["dir"] / "o")


def test_sizes_against_a_small_machine(files, capsys, monkeypatch):
    # Against 512 kB of available memory, ordinary requests are refused before any work, naming
    # what asked for it; the same requests run on the real machine (checked elsewhere).
    monkeypatch.setattr(memory, "available_bytes", lambda: 2**19)
    big = files["dir"] / "big.json"
    n = 4000
    big.write_text(
        json.dumps({"thresholds": np.linspace(0, 2, n, endpoint=False).tolist(), "weights": [1.0] * n, "offset": 0.0})
    )
    cases = [
        (["compensate", str(big), files["rec"]], f"{big} (4000 plays) on {files['rec']} (300 samples) needs about"),
        (["simulate", "--plays", "200", "--r-max", "1"], "1001 samples x 200 plays needs about"),
        (["fit", files["rec"], "--starts", "64"], "--starts 64 on"),
        (["diagnose", files["rec"]], f"{files['rec']} (300 samples) needs about"),
    ]
    for argv, needle in cases:
        _refused(capsys, argv, needle, files["dir"] / "o")


def test_compensation_outside_the_fitted_range_is_refused(files, capsys):
    model = files["dir"] / "fit.json"
    model.write_text(json.dumps(MODEL | {"input_range": [-0.5, 0.5]}))
    out = files["dir"] / "o"
    # Far outside (beyond the 5% margin): refused in one line, nothing written.
    code, o, err = _run(capsys, ["compensate", str(model), files["rec"], "--out", str(out)], stop=False)
    assert (code, o) == (2, "") and err.count("\n") == 1, err
    assert "leaves the input range the model was fitted on by more than 5% of its width" in err
    assert "[-0.5, 0.5]" in err and "--extrapolate" in err
    assert not out.exists() or not any(out.iterdir())
    # Asked for: written, the fraction outside noted and recorded.
    argv = ["compensate", str(model), files["rec"], "--out", str(out), "--extrapolate"]
    code, _, err = _run(capsys, argv, stop=False)
    assert code == 0, err
    rep = json.loads((out / "compensate.json").read_text())
    u = np.loadtxt(out / "compensate.csv", delimiter=",", skiprows=1)[:, 2]
    n_out = int(np.sum(np.abs(u) > 0.5))
    assert 0 < n_out < u.size
    assert rep["fitted_input_range"] == [-0.5, 0.5]
    assert rep["fraction_outside_fitted_range"] == pytest.approx(n_out / u.size)
    assert err.count("\n") == 1 and f"note: {n_out} of {u.size} samples ({n_out / u.size:.1%})" in err
    # Outside by less than the margin: written, with the note.
    lo, hi = float(u.min()), float(u.max())
    inner = [lo + 0.01 * (hi - lo), hi - 0.01 * (hi - lo)]
    model.write_text(json.dumps(MODEL | {"input_range": inner}))
    code, _, err = _run(capsys, ["compensate", str(model), files["rec"], "--out", str(out), "--force"], stop=False)
    assert code == 0 and "of the feedforward input lie outside" in err, err
    # Inside the range: no note, fraction 0; a model file that does not say: no such keys.
    model.write_text(json.dumps(MODEL | {"input_range": [-10.0, 10.0]}))
    code, _, err = _run(capsys, ["compensate", str(model), files["rec"], "--out", str(out), "--force"], stop=False)
    assert code == 0 and err == ""
    assert json.loads((out / "compensate.json").read_text())["fraction_outside_fitted_range"] == 0.0
    model.write_text(json.dumps(MODEL))
    code, _, err = _run(capsys, ["compensate", str(model), files["rec"], "--out", str(out), "--force"], stop=False)
    assert code == 0 and err == ""
    assert "fraction_outside_fitted_range" not in json.loads((out / "compensate.json").read_text())


def test_fit_records_the_input_range_it_saw(files, capsys):
    out = files["dir"] / "o"
    code, _, err = _run(
        capsys,
        [
            "fit",
            files["rec"],
            "--model",
            "pi",
            "--plays",
            "2",
            "--starts",
            "2",
            "--max-steps",
            "20",
            "--quiet",
            "--out",
            str(out),
        ],
        stop=False,
    )
    assert code == 0, err
    assert json.loads((out / "fit.json").read_text())["input_range"] == [float(U.min()), float(U.max())]


def test_a_failed_write_names_the_result_not_the_temporary(files, capsys, monkeypatch):
    # A full disk at the end of a run: one line naming the result file, nothing left behind.
    import errno

    from piest_jax._cli import output as _io

    def full(fd):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(_io.os, "fsync", full)
    out = files["dir"] / "o"
    code, o, err = _run(capsys, ["simulate", "--duration", "0.05", "--out", str(out)], stop=False)
    assert (code, o) == (2, "")
    assert (
        err == f"piest simulate: error: {out / 'simulate.csv'}: cannot write it (No space left on device); "
        "nothing was written\n"
    )
    assert not out.exists()


def test_a_long_levenberg_marquardt_fit_is_sized_by_its_chunks():
    # Past 2^16 samples LM accumulates normal equations chunk by chunk: memory grows with a few
    # copies of the record, not with samples x parameters x starts (a 10^7-sample fit measured
    # 1.25 GB); other solvers hold the whole Jacobian.
    from piest_jax._cli.memory import fit_bytes

    chunked = fit_bytes(10**7, 4, 40, chunked_past=2**16)
    assert 0.5 * 2**30 < chunked < 2 * 2**30 < fit_bytes(10**7, 4, 40) / 10
    assert fit_bytes(1000, 4, 40, chunked_past=2**16) == fit_bytes(1000, 4, 40)


def test_compensation_is_clipped_or_slew_limited_on_request(files, capsys):
    model = files["dir"] / "fit.json"
    model.write_text(json.dumps(MODEL | {"input_range": [-0.5, 0.5]}))

    def run(name, *extra):
        out = files["dir"] / name
        code, _, err = _run(capsys, ["compensate", str(model), files["rec"], "--out", str(out), *extra], stop=False)
        rows = np.loadtxt(out / "compensate.csv", delimiter=",", skiprows=1) if code == 0 else None
        rep = json.loads((out / "compensate.json").read_text()) if code == 0 else None
        return code, err, rows, rep

    code, err, free, _ = run("free", "--extrapolate")
    assert code == 0, err
    t, u_free = free[:, 0], free[:, 2]
    # --clip holds it inside the fitted range, and the model column is the model's output for it.
    code, err, rows, rep = run("clip", "--clip")
    assert code == 0, err
    np.testing.assert_array_equal(rows[:, 2], np.clip(u_free, -0.5, 0.5))
    assert rep["n_clipped"] == int(np.sum(np.abs(u_free) > 0.5)) > 0
    assert rep["fraction_outside_fitted_range"] == 0.0
    # --max-slew refuses a faster feedforward, or with --clip limits it sample by sample.
    rate = float(np.max(np.abs(np.diff(u_free) / np.diff(t))))
    slew = str(0.5 * rate)
    code, err, _, _ = run("slow", "--extrapolate", "--max-slew", slew)
    assert code == 2 and f"faster than --max-slew {0.5 * rate:.6g}" in err and "--clip" in err
    code, err, rows, rep = run("slow2", "--clip", "--max-slew", slew)
    assert code == 0, err
    assert np.max(np.abs(np.diff(rows[:, 2]) / np.diff(t))) <= 0.5 * rate * (1 + 1e-9)
    assert rep["max_rate"] <= 0.5 * rate * (1 + 1e-9) and np.all(np.abs(rows[:, 2]) <= 0.5)
    # A feedforward faster than anything the model was fitted on is noted.
    model.write_text(json.dumps(MODEL | {"input_range": [-10.0, 10.0], "input_max_rate": 0.1 * rate}))
    code, err, _, _ = run("noted")
    assert code == 0 and "faster than anything in the record the model was fitted on" in err
    code, err, _, _ = run("both", "--clip", "--extrapolate")
    assert code == 2 and "either --clip or --extrapolate" in err
