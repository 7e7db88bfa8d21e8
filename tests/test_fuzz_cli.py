"""Every `piest` command on hostile input: either a correct result, or exit code 2 with one line on
stderr naming the file, the row and the problem, nothing on stdout, nothing written, never a
traceback or an internal error.

- Bad data files (empty, header only, wrong or duplicated names, text, NaN/inf, repeated or
  decreasing time, gaps, one sample, short rows, binary) through every command that reads one,
  random files and random options (hypothesis) through every command, bad model files.
- Correct results where the data are unusual but valid: constant, tiny and huge inputs
  (simulate), a constant output (fit), u and y in units from 1e-9 to 1e9 (fit, compensate).

Commands run in-process through `piest_jax._cli.main`; one test runs the installed `piest` script
in a subprocess to prove the real entry point behaves the same.
"""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import reference as ref
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from piest_jax._cli import COMMANDS, build_parser, main
from piest_jax._cli import compensate as compensate_cmd
from piest_jax._cli import excite as excite_cmd
from piest_jax._cli import fit as fit_cmd
from piest_jax._cli import fit_saturating as fit_saturating_cmd
from piest_jax._cli import montecarlo as montecarlo_cmd
from piest_jax._cli import reproduce as reproduce_cmd
from piest_jax._cli import simulate as simulate_cmd
from piest_jax._diagnosis import diagnose as _diagnose
from piest_jax._estimation import online as _online

pytestmark = pytest.mark.long

NAMES = [m.NAME for m in COMMANDS]


def _subparsers():
    action = next(a for a in build_parser()._actions if a.dest == "command")
    return action.choices


# How each command takes one data file (and the other options it needs to get to reading it).
# montecarlo, reproduce and excite read no files; a new command must be added to one of the two lists.
DATA_ARGV = {
    "simulate": lambda f, model: ["--input", "csv", "--csv", f],
    "fit": lambda f, model: [f, "--plays", "2"],
    "diagnose": lambda f, model: [f],
    "compensate": lambda f, model: [model, f],
    "estimate": lambda f, model: [f],
}
NO_DATA = ["montecarlo", "reproduce", "excite"]
DATA_COMMANDS = list(DATA_ARGV)

# compensate reads the desired output (columns t and desired, else y) with `load_columns`: a
# record of t, u, y is a valid desired trajectory for it whatever u holds, and it needs no uniform
# sampling, so a few files are fine for it and one names what it looks for differently.
_COMPENSATE_NEEDLE = {
    "wrong_names": "no header row naming the column t was found",
    "missing_y": "no column `y` in the header (t, u)",
    "nan": None,
    "gap": None,
}

GOOD_MODEL = {"thresholds": [0.0, 0.5], "weights": [1.0, 0.5], "offset": 0.1, "initial_states": [0.0, 0.0]}


def test_every_command_is_fuzzed():
    assert sorted(DATA_COMMANDS + NO_DATA) == sorted(NAMES)


def _run(capsys, argv):
    try:
        code = main(argv)
    except SystemExit as e:  # argparse
        code = e.code
    out, err = capsys.readouterr()
    return code, out, err


def _assert_one_line_error(code, out, err, *needles):
    assert code == 2, err
    assert out == ""
    assert err.count("\n") == 1 and err.endswith("\n"), err
    assert "Traceback" not in err and "internal error" not in err
    assert err.startswith("piest"), err
    for n in needles:
        assert n in err, (n, err)


def _t(n, dt=0.01):
    return dt * np.arange(n)


def _table(t, u, y):
    return "t,u,y\n" + "".join(f"{float(a)!r},{float(b)!r},{float(c)!r}\n" for a, b, c in zip(t, u, y))


def _sine_rows(n=300):
    t = _t(n)
    u = 2 * np.sin(2 * np.pi * t)
    return t, u, 0.5 * u + 0.1 * np.cos(2 * np.pi * t)


def _bad_files():
    """(name, text or bytes, what the message must say)."""
    t, u, y = _sine_rows()
    lines = _table(t, u, y).splitlines()

    def edit(row, text):
        ls = list(lines)
        ls[row - 1] = text
        return "\n".join(ls) + "\n"

    return [
        ("empty", "", "the file is empty"),
        ("header_only", "t,u,y\n", "no data rows follow"),
        ("wrong_names", "time,volts,um\n0,1,2\n", "no header row naming the columns t, u and y"),
        ("missing_y", "t,u\n0,1\n0.1,2\n", "missing column(s) y"),
        ("dup_names", "t,u,y,y\n0,1,2,3\n", "row 1: duplicated column name(s) in the header: y"),
        ("text_cell", edit(40, f"{float(t[38])!r},0.1,n/a"), "row 40: cell 3 is not a number: 'n/a' (column `y`)"),
        ("nan", edit(17, f"{float(t[15])!r},nan,1"), "row 17: column `u` holds nan"),
        ("inf", edit(200, f"{float(t[198])!r},1,-inf"), "row 200: column `y` holds -inf"),
        ("repeat_t", edit(9, f"{float(t[6])!r},1,1"), "row 9: time is not strictly increasing"),
        ("backwards_t", edit(50, "0.2,1,1"), "row 50: time is not strictly increasing: t = 0.2 goes backwards"),
        (
            "gap",
            "t,u,y\n"
            + "".join(f"{float(a + (a > 1) * 0.5)!r},{float(b)!r},{float(c)!r}\n" for a, b, c in zip(t, u, y)),
            "row 103: non-uniform sampling",
        ),
        ("one_sample", "t,u,y\n0,1,2\n", "only 1 sample"),
        ("short_row", edit(5, "0.03,1"), "row 5: expected 3 cells as in the header, found 2"),
        ("binary", bytes(range(256)) * 3, "is not a text (UTF-8) CSV file"),
    ]


BAD = _bad_files()


@pytest.fixture(scope="module")
def bad_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("bad")
    for name, content, _ in BAD:
        p = d / f"{name}.csv"
        (p.write_bytes if isinstance(content, bytes) else p.write_text)(content)
    (d / "model.json").write_text(json.dumps(GOOD_MODEL))
    return d


@pytest.mark.parametrize("command", DATA_COMMANDS)
def test_bad_data_files_give_one_line_and_write_nothing(command, bad_dir, tmp_path, capsys):
    argv = DATA_ARGV[command]
    model = str(bad_dir / "model.json")
    for name, _, needle in BAD:
        if command == "compensate":
            needle = _COMPENSATE_NEEDLE.get(name, needle)
            if needle is None:
                continue
        path = str(bad_dir / f"{name}.csv")
        out = tmp_path / name
        code, o, err = _run(capsys, [command, *argv(path, model), "--out", str(out)])
        _assert_one_line_error(code, o, err, path, needle)
        assert not out.exists() or not any(out.iterdir()), name


@pytest.mark.parametrize("command", DATA_COMMANDS)
def test_missing_file_and_folder(command, bad_dir, tmp_path, capsys):
    argv = DATA_ARGV[command]
    model = str(bad_dir / "model.json")
    for path, needle in [(tmp_path / "absent.csv", "no such file"), (tmp_path, "is a folder")]:
        code, o, err = _run(capsys, [command, *argv(str(path), model), "--out", str(tmp_path / "o")])
        _assert_one_line_error(code, o, err, str(path), needle)


@pytest.mark.parametrize(
    "content, needle",
    [
        ("", "not a JSON file"),
        ("{thresholds: [0]}", "not a JSON file"),
        ("[1, 2]", "expected a JSON object as written by `piest fit`"),
        ({"thresholds": [0.0, 0.5]}, "missing weights"),
        ({"thresholds": [0.0, 0.5], "weights": [1.0, "a"]}, "must be numbers"),
        ({"thresholds": [0.0, 0.5], "weights": [1.0, None]}, "must be finite"),
        ('{"thresholds": [0, 0.5], "weights": [NaN, 1]}', "must be finite"),
        ({"thresholds": [[0.0, 0.5]], "weights": [[1.0, 1.0]]}, "must be equal vectors"),
        ({"thresholds": [], "weights": []}, "the model has no plays"),
        (
            {"thresholds": [0.0, 0.5], "weights": [1.0, 1.0], "initial_states": [1, 2, 3]},
            "initial_states has 3 entries for 2 plays",
        ),
        ({"thresholds": [0.0, 0.5], "weights": [1.0, 1.0], "offset": "x"}, "must be numbers"),
        ({"thresholds": [0.0, 0.5], "weights": [1.0, -2.0]}, "not invertible"),
        ({"thresholds": [0.0, 0.5], "weights": [0.0, 0.0]}, "not invertible"),
        ({"thresholds": [0.2, 0.5], "weights": [1.0, 0.5]}, "needs r_1 = 0"),
        ({"thresholds": [0.5, 0.0], "weights": [1.0, 1.0]}, "must be strictly increasing"),
        ({"thresholds": [0.0, -0.5], "weights": [1.0, 1.0]}, "must be non-negative"),
    ],
)
def test_compensate_refuses_bad_models_in_one_line(content, needle, tmp_path, capsys):
    model = tmp_path / "fit.json"
    model.write_text(content if isinstance(content, str) else json.dumps(content))
    t = 0.01 * np.arange(50)
    desired = tmp_path / "desired.csv"
    desired.write_text(_table(t, np.zeros_like(t), np.sin(2 * np.pi * t)))
    out = tmp_path / "o"
    code, o, err = _run(capsys, ["compensate", str(model), str(desired), "--out", str(out)])
    _assert_one_line_error(code, o, err, f"{model}: ", needle)
    assert not out.exists() or not any(out.iterdir())


def test_simulate_on_constant_tiny_and_huge_inputs_is_correct(tmp_path, capsys):
    r, w = [0.0, 0.25, 0.5], [1.0, 0.5, 0.25]
    t = _t(64)
    cases = {
        "constant": np.full(64, 0.3),
        "tiny": 1e-9 * np.sin(t * 7),
        "huge": 1e9 * np.sin(t * 7),
    }
    for name, u in cases.items():
        src = tmp_path / f"{name}.csv"
        src.write_text(_table(t, u, np.zeros_like(u)))
        out = tmp_path / f"o_{name}"
        code, o, err = _run(
            capsys,
            [
                "simulate",
                "--input",
                "csv",
                "--csv",
                str(src),
                "--out",
                str(out),
                "--thresholds",
                "0,0.25,0.5",
                "--weights",
                "1,0.5,0.25",
            ],
        )
        assert code == 0, err
        data = np.loadtxt(out / "simulate.csv", delimiter=",", skiprows=1)
        np.testing.assert_array_equal(data[:, 1], u)
        np.testing.assert_allclose(data[:, 2], ref.pi(u, r, w), rtol=1e-12, atol=1e-12 * np.abs(u).max())


SCALE_PAIRS = [(1.0, 1.0), (1e-6, 1e6), (1e6, 1e-6), (1e-9, 1e9)]


def test_fit_finds_the_model_in_the_users_units_at_any_scale(tmp_path, capsys):
    # Data from a known two-play model, with u and y in units from 1e-9 to 1e9: the fit (which
    # normalises internally) reports the same model, converted to the user's units, every time.
    t = _t(300)
    u = 2 * np.sin(2 * np.pi * t) * (1 + 0.3 * np.sin(2 * np.pi * 0.37 * t))
    y = ref.pi(u, [0.0, 0.6], [1.0, 0.5], x0=u[0]) + 0.2
    for su, sy in SCALE_PAIRS:
        src = tmp_path / "rec.csv"
        src.write_text(_table(t, su * u, sy * y))
        out = tmp_path / f"o{su:g}"
        code, o, err = _run(
            capsys,
            ["fit", str(src), "--plays", "2", "--starts", "2", "--max-steps", "60", "--out", str(out), "--quiet"],
        )
        assert code == 0, err
        rep = json.loads((out / "fit.json").read_text(), parse_constant=lambda c: pytest.fail(c))
        np.testing.assert_allclose(np.array(rep["thresholds"]) / su, [0.0, 0.6], atol=1e-6)
        np.testing.assert_allclose(np.array(rep["weights"]) * su / sy, [1.0, 0.5], rtol=1e-6)
        assert rep["offset"] / sy == pytest.approx(0.2, rel=1e-6)
        assert rep["rmse"] / sy < 1e-8


def test_fit_on_flat_records(tmp_path, capsys):
    t, u, y = _sine_rows()
    flat_u = tmp_path / "flat_u.csv"
    flat_u.write_text(_table(t, np.full_like(u, 1.5), y))
    code, o, err = _run(capsys, ["fit", str(flat_u), "--plays", "2", "--out", str(tmp_path / "a")])
    _assert_one_line_error(code, o, err, f"{flat_u}: the input u is constant (1.5)")
    # A constant output is data: the fit is the offset, with no hysteresis left to explain.
    flat_y = tmp_path / "flat_y.csv"
    flat_y.write_text(_table(t, u, np.full_like(y, -2.0)))
    out = tmp_path / "b"
    code, o, err = _run(
        capsys, ["fit", str(flat_y), "--plays", "2", "--starts", "2", "--max-steps", "60", "--out", str(out), "--quiet"]
    )
    assert code == 0, err
    rep = json.loads((out / "fit.json").read_text(), parse_constant=lambda c: pytest.fail(c))
    assert rep["offset"] == pytest.approx(-2.0, abs=1e-2)
    assert rep["rmse"] < 1e-2 and all(np.isfinite(rep["weights"] + rep["thresholds"]))


def test_compensate_inverts_in_the_users_units_at_any_scale(tmp_path, capsys):
    t = _t(200)
    yd = 1.5 * np.sin(2 * np.pi * t) + 0.5 * np.sin(2 * np.pi * 3 * t)
    r, w, c = np.array([0.0, 0.4, 0.9]), np.array([1.0, 0.6, 0.3]), 0.25
    first = None
    for su, sy in SCALE_PAIRS:
        model = tmp_path / "fit.json"
        model.write_text(
            json.dumps(
                {
                    "thresholds": (su * r).tolist(),
                    "weights": (w * sy / su).tolist(),
                    "offset": c * sy,
                    "initial_states": [0.0, 0.0, 0.0],
                }
            )
        )
        desired = tmp_path / "desired.csv"
        desired.write_text("t,desired\n" + "".join(f"{a!r},{b!r}\n" for a, b in zip(t.tolist(), (sy * yd).tolist())))
        out = tmp_path / f"o{su:g}"
        code, o, err = _run(capsys, ["compensate", str(model), str(desired), "--out", str(out), "--quiet"])
        assert code == 0, err
        res = np.loadtxt(out / "compensate.csv", delimiter=",", skiprows=1)
        u = res[:, 2] / su
        assert np.all(np.isfinite(u))
        # The model driven by the feedforward input follows the desired output (checked here
        # with the reference operator, in unit scale), and the input does not depend on the units.
        np.testing.assert_allclose(ref.pi(u, r, w) + c, yd, atol=1e-9)
        first = u if first is None else first
        np.testing.assert_allclose(u, first, rtol=1e-9, atol=1e-12)


def test_diagnose_refuses_records_it_cannot_use(tmp_path, capsys):
    t, u, y = _sine_rows()
    cases = {
        "constant_u": (np.full_like(u, 1.5), y, "no excitation: the input u is constant"),
        "constant_y": (u, np.full_like(y, -2.0), "constant output"),
        "monotone_u": (t.copy(), y, "never reverses direction"),
        "short": (u[:150], y[:150], "too short: 150 samples"),
    }
    for name, (uu, yy, needle) in cases.items():
        p = tmp_path / f"{name}.csv"
        p.write_text(_table(t[: len(uu)], uu, yy))
        code, o, err = _run(capsys, ["diagnose", str(p), "--out", str(tmp_path / name)])
        _assert_one_line_error(code, o, err, str(p), needle)


def test_diagnose_checks_the_validation_record_before_searching(tmp_path, capsys, monkeypatch):
    def must_not_run(*a, **k):
        raise AssertionError("the search started before the inputs were checked")

    monkeypatch.setattr(_diagnose, "search", must_not_run)
    t, u, y = _sine_rows()
    good, flat = tmp_path / "good.csv", tmp_path / "flat.csv"
    good.write_text(_table(t, u, y))
    flat.write_text(_table(t, u, np.ones_like(y)))
    code, o, err = _run(capsys, ["diagnose", str(good), "--validate", str(flat), "--out", str(tmp_path / "o")])
    _assert_one_line_error(code, o, err, str(flat), "constant output")


@pytest.mark.parametrize(
    "argv, needle",
    [
        (["simulate", "--dt", "2"], "--dt 2 is longer than --duration 1"),
        (["simulate", "--duration", "1e9"], "gives 1e+12 samples; at most 1e+07"),
        (["simulate", "--dt", "1e-300"], "gives 1e+300 samples"),
        (["simulate", "--amplitude", "1e308"], "the input u overflows float64"),
        (["simulate", "--weights=1e308,1e308,1e308"], "the output y overflows float64"),
        (["simulate", "--plays", "100000", "--r-max", "1"], "1001 samples x 100000 plays"),
        (["simulate", "--weights", "-1,0,1"], "a value starting with '-' is written --option=-1,2"),
        (["simulate", "--dt", "nan"], "argument --dt: must be a positive finite number"),
        (["simulate", "--thresholds", ""], "argument --thresholds: expected at least one number"),
        (["simulate", "--out", "/proc/no/such/place"], "/proc/no/such/place"),
        (["reproduce", "fig9"], "argument figure: invalid choice: 'fig9'"),
        (["reproduce", "fig5", "--P0", "inf"], "argument --P0: must be a positive finite number"),
        (["diagnose"], "the following arguments are required: DATA.csv"),
        (["diagnose", "x.csv", "--max-effects", "0"], "--max-effects must be at least 1, got 0"),
        (["montecarlo", "--window", "99999", "--samples", "100"], "--window (99999 samples) is longer than the signal"),
        (["montecarlo", "--families", "nope"], "unknown --families ['nope']"),
        (["montecarlo", "--samples", "1"], "--samples must be at least 2, got 1"),
        (["fit", "x.csv", "--plays", "0"], "argument --plays: must be positive, got 0"),
        (["fit", "x.csv", "--initial-states", "1", "--fit-initial-states"], "not both"),
        (["compensate", "a.json"], "the following arguments are required: DESIRED.csv"),
        (["nonsense"], "invalid choice: 'nonsense'"),
        ([], "the following arguments are required: COMMAND"),
    ],
)
def test_bad_requests_give_one_line(argv, needle, tmp_path, capsys):
    if "--out" not in argv and argv and argv[0] in NAMES:
        argv = [*argv, "--out", str(tmp_path / "o")]
    code, o, err = _run(capsys, argv)
    _assert_one_line_error(code, o, err, needle)
    assert not (tmp_path / "o").exists() or not any((tmp_path / "o").iterdir())


class _Reached(BaseException):
    """Raised where a command starts its real computation: the arguments were accepted."""


def _reached(*args, **kwargs):
    raise _Reached


# Where each command's computation starts: the fuzz below stops there once the arguments and
# inputs are accepted (simulate is cheap and runs until it writes).
_STUBS = {
    "simulate": [(simulate_cmd._io, "write_csv")],
    "fit": [(fit_cmd, "identify"), (fit_saturating_cmd, "identify")],
    "diagnose": [(_diagnose, "diagnose")],
    "compensate": [(compensate_cmd, "feedforward")],
    "montecarlo": [(montecarlo_cmd, "pe_map")],
    "reproduce": [(reproduce_cmd, "reproduce")],
    "estimate": [(_online, "estimate_record")],
    "excite": [(excite_cmd, "design_input")],
}

_JUNK = ["nan", "inf", "-inf", "-1", "0", "1e308", "1e-320", "", "abc", "1,,2", "3", "0,1", "--", "2.5"]


def _options(name):
    """(option, number of values, choices) of every option but --out and --help."""
    sub = _subparsers()[name]
    return [
        (a.option_strings[-1], a.nargs, a.choices)
        for a in sub._actions
        if a.option_strings and a.dest not in ("help", "out")
    ]


@pytest.fixture(scope="module")
def fuzz_inputs(tmp_path_factory):
    d = tmp_path_factory.mktemp("fuzz")
    t, u, y = _sine_rows()
    (d / "rec.csv").write_text(_table(t, u, y))
    (d / "model.json").write_text(json.dumps(GOOD_MODEL))
    return d


@pytest.mark.parametrize("command", NAMES)
@settings(max_examples=30, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_argument_fuzz_runs_or_fails_in_one_line(command, fuzz_inputs, tmp_path, capsys, data):
    # Random options with junk or valid values, on a good record: the command either accepts them
    # and starts computing, or stops with one line and exit 2; never an internal error (exit 1),
    # a traceback, or a file written.
    rec, model = str(fuzz_inputs / "rec.csv"), str(fuzz_inputs / "model.json")
    argv = [command, *(DATA_ARGV[command](rec, model) if command in DATA_ARGV else [])]
    if command == "simulate":
        argv = [command]
    if command == "reproduce":
        argv.append(data.draw(st.sampled_from(["fig5", "fig6", "all", "fig7", "-1"])))
    for _ in range(data.draw(st.integers(0, 4))):
        opt, nargs, choices = data.draw(st.sampled_from(_options(command)))
        argv.append(opt)
        if nargs != 0:
            values = _JUNK + [rec] + (list(choices) if choices else [])
            argv.append(data.draw(st.sampled_from(values)))
    out = tmp_path / f"o{data.draw(st.integers(0, 10**9))}"
    with pytest.MonkeyPatch.context() as mp:
        for mod, attr in _STUBS[command]:
            mp.setattr(mod, attr, _reached)
        try:
            code, o, err = _run(capsys, [*argv, "--out", str(out), "--quiet"])
        except _Reached:
            capsys.readouterr()
            return
    assert code == 2, (argv, err)
    assert o == ""
    assert err.count("\n") == 1 and "error: " in err and "Traceback" not in err, (argv, err)
    assert not out.exists() or not any(out.iterdir())


class _NoOperator:
    """simulate's operator, stopped where the computation would start."""

    n_plays = 3

    def __init__(self, *args, **kwargs):
        pass

    def regressor(self, u):
        raise _Reached


_CELLS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True, width=32).map(repr),
    st.sampled_from(["", " ", "nan", "-", "1e999", "1e-9", "1e9", "0x10", '"1"', "1,5", "t", "y"]),
    st.text(alphabet=st.characters(codec="utf-8", exclude_characters="\r\n"), max_size=5),
)


@settings(max_examples=60, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    command=st.sampled_from(DATA_COMMANDS),
    header=st.lists(st.sampled_from(["t", "u", "y", "desired", "x", "", "T"]), max_size=5),
    body=st.lists(st.lists(_CELLS, max_size=5), max_size=12),
    delim=st.sampled_from([",", ";", "\t"]),
    preamble=st.booleans(),
)
def test_random_files_through_every_data_command(
    fuzz_inputs, tmp_path_factory, capsys, command, header, body, delim, preamble
):
    # Whatever the file holds, a command either accepts it and starts computing, or stops with one
    # line naming the file, exit 2, nothing written.
    d = tmp_path_factory.mktemp("rnd")
    f = d / "data.csv"
    text = ("Scope export v1\n" if preamble else "") + delim.join(header) + "\n"
    f.write_text(text + "\n".join(delim.join(row) for row in body), encoding="utf-8")
    argv = [command, *DATA_ARGV[command](str(f), str(fuzz_inputs / "model.json")), "--out", str(d / "o")]
    with pytest.MonkeyPatch.context() as mp:
        for mod, attr in _STUBS[command]:
            mp.setattr(mod, attr, _reached)
        mp.setattr(simulate_cmd, "PIOperator", _NoOperator)
        try:
            code, o, err = _run(capsys, argv)
        except _Reached:
            capsys.readouterr()
            return
    _assert_one_line_error(code, o, err, str(f))
    assert not (d / "o").exists() or not any((d / "o").iterdir())


def test_the_installed_piest_script_fails_in_one_line(tmp_path):
    script = shutil.which("piest", path=str(Path(sys.executable).parent)) or shutil.which("piest")
    assert script, "the `piest` console script is not installed"
    bad = tmp_path / "scope export.csv"
    bad.write_text("Instrument X\nt,u,y\n0,1,2\n0.1,oops,3\n")
    proc = subprocess.run(
        [script, "simulate", "--input", "csv", "--csv", str(bad), "--out", str(tmp_path / "o")],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 2
    assert proc.stdout == ""
    assert proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr
    assert f"{bad}, row 4: cell 2 is not a number: 'oops' (column `u`)" in proc.stderr


def test_a_closed_output_pipe_stops_quietly(tmp_path, capsys):
    # `piest simulate ... | head -0`: the reader leaves before the paths are printed. The results
    # are complete, the exit code is 141 (as after SIGPIPE) and nothing is said about it.
    script = shutil.which("piest", path=str(Path(sys.executable).parent)) or shutil.which("piest")
    out = tmp_path / "o"
    argv = ["simulate", "--duration", "0.05", "--out"]
    env = dict(os.environ, PYTHONHASHSEED="123")
    proc = subprocess.Popen([script, *argv, str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
    proc.stdout.close()
    with proc.stderr:
        err = proc.stderr.read().decode()
    assert proc.wait(timeout=300) == 141, err
    assert err == ""
    assert sorted(p.name for p in out.iterdir()) == ["loop.png", "simulate.csv", "simulate.json"]
    assert json.loads((out / "simulate.json").read_text())["n_samples"] == 51
    # Another process (another hash seed) writes the same bytes as this one.
    assert _run(capsys, [*argv, str(tmp_path / "here")])[0] == 0
    for p in out.iterdir():
        assert p.read_bytes() == (tmp_path / "here" / p.name).read_bytes(), p.name
