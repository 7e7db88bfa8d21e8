"""`piest simulate`, run in-process: what it writes, overwrite protection, exit codes, messages."""

import json
import re

import numpy as np
import pytest
import reference as ref
from test_creep import reference_lags

from piest_jax._cli import main
from piest_jax._data.record import load_record


def _run(capsys, *argv):
    code = main(["simulate", *argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_default_run_writes_csv_plot_and_json(tmp_path, capsys):
    out_dir = tmp_path / "sim"
    code, out, err = _run(capsys, "--out", str(out_dir), "--quiet")
    assert code == 0, err
    names = ["simulate.csv", "loop.png", "simulate.json"]
    assert out.split() == [str(out_dir / n) for n in names]
    assert (out_dir / "loop.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    rec = load_record(out_dir / "simulate.csv")
    t = 1e-3 * np.arange(1001)
    np.testing.assert_allclose(rec.t, t, rtol=0, atol=1e-15)
    np.testing.assert_allclose(rec.u, 10 * np.sin(2 * np.pi * 5 * t), rtol=0, atol=1e-12)
    r, w = [0.0, 10 / 3, 20 / 3], [1.0, 3.0, 5.0]
    np.testing.assert_allclose(rec.y, ref.pi(rec.u, r, w), rtol=0, atol=1e-10)
    H = ref.play(rec.u, r)
    for j in range(3):
        np.testing.assert_allclose(rec.extras[f"x_{j + 1}"], H[:, j], rtol=0, atol=1e-12)
    summary = json.loads((out_dir / "simulate.json").read_text())
    assert summary["weights"] == w and summary["n_samples"] == 1001
    np.testing.assert_allclose(summary["final_states"], H[-1], atol=1e-12)

    # A second run into the same folder refuses to overwrite, naming the file.
    code, out, err = _run(capsys, "--out", str(out_dir))
    assert code == 2 and out == ""
    assert err.count("\n") == 1
    assert "simulate.csv already exists; pass --force to overwrite it" in err
    assert err.startswith("piest simulate: error: ")


def test_force_overwrites_and_options_are_used(tmp_path, capsys):
    out_dir = tmp_path / "tri"
    (out_dir).mkdir()
    (out_dir / "simulate.csv").write_text("old\n")
    args = ["--input", "triangle", "--amplitude", "4", "--frequency", "2.5", "--duration", "0.5"]
    args += ["--dt", "0.01", "--thresholds", "0,1,2", "--weights", "1,0.5,-0.25"]
    args += ["--initial-states", "0,0.3,-0.2", "--out", str(out_dir), "--force", "--quiet"]
    code, _, err = _run(capsys, *args)
    assert code == 0, err
    rec = load_record(out_dir / "simulate.csv")
    assert rec.n_samples == 51
    assert (rec.u.max(), rec.u.min()) == pytest.approx((4.0, -4.0))  # peaks at t = 0.1, 0.3
    want = ref.pi(rec.u, [0, 1, 2], [1, 0.5, -0.25], [0, 0.3, -0.2])
    np.testing.assert_allclose(rec.y, want, rtol=0, atol=1e-12)


def test_csv_input(tmp_path, capsys):
    t = 0.01 * np.arange(40)
    u = 3 * np.sin(2 * np.pi * t)
    src = tmp_path / "in.csv"
    src.write_text("t,u,y\n" + "".join(f"{a:.17g},{b:.17g},0\n" for a, b in zip(t, u)))
    out_dir = tmp_path / "csv"
    code, _, err = _run(
        capsys,
        "--input",
        "csv",
        "--csv",
        str(src),
        "--plays",
        "4",
        "--r-max",
        "2",
        "--out",
        str(out_dir),
        "--quiet",
    )
    assert code == 0, err
    rec = load_record(out_dir / "simulate.csv")
    np.testing.assert_allclose(rec.u, u, rtol=0, atol=1e-15)
    np.testing.assert_allclose(rec.y, ref.pi(u, [0, 0.5, 1.0, 1.5], [0.25] * 4), atol=1e-12)


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--input", "csv"], "--input csv needs --csv FILE"),
        (["--csv", "x.csv"], "--csv is only used with --input csv, not --input sine"),
        (["--input", "csv", "--csv", "absent.csv"], "absent.csv: no such file"),
        (["--thresholds", "0,1", "--plays", "3", "--r-max", "1"], "either --thresholds or --plays"),
        (["--plays", "3"], "--plays needs --r-max"),
        (["--r-max", "2"], "--r-max is only used with --plays"),
        (["--thresholds", "0,1,2", "--weights", "1,2"], "2 weights for 3 thresholds"),
        (["--initial-states", "0,1"], "2 initial states for 3 thresholds; give 1 or 3"),
        (["--thresholds", "0,2,1"], "`thresholds` must be strictly increasing"),
        (["--thresholds=-1,2"], "`thresholds` must be non-negative"),
        (["--input", "multisine", "--amplitude", "1,2"], "multisine: 2 amplitudes but 1 freq"),
        (["--input", "sine", "--amplitude", "1,2"], "--input sine takes one amplitude"),
    ],
)
def test_bad_requests_give_one_line_and_exit_2(tmp_path, capsys, argv, message):
    code, out, err = _run(capsys, *argv, "--out", str(tmp_path / "o"), "--quiet")
    assert code == 2
    assert out == ""
    assert err.count("\n") == 1 and "Traceback" not in err
    assert err.startswith("piest simulate: error: ")
    assert message in err


def test_out_is_a_file(tmp_path, capsys):
    f = tmp_path / "file"
    f.write_text("")
    code, _, err = _run(capsys, "--out", str(f))
    assert code == 2 and "exists and is not a folder" in err


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--dt", "-1"], "argument --dt: must be a positive finite number, got -1"),
        (["--plays", "zero"], "argument --plays: expected a whole number, got 'zero'"),
        (["--thresholds", "0,a"], "argument --thresholds: expected comma-separated numbers"),
        (["--weights", "1,nan"], "argument --weights: NaN or inf"),
        (["--input", "square"], "argument --input: invalid choice: 'square'"),
        (["--no-such-option"], "unrecognized arguments: --no-such-option"),
    ],
)
def test_argument_errors_exit_2(capsys, argv, message):
    with pytest.raises(SystemExit) as exc:
        main(["simulate", *argv])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    # argparse prints the usage, then one line naming the problem.
    # Unknown options are reported by the top-level parser ("piest: error: ...").
    assert re.match(r"piest( simulate)?: error: ", err.strip().splitlines()[-1])
    assert message in err.strip().splitlines()[-1]


def test_help_describes_outputs(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["simulate", "--help"])
    assert exc.value.code == 0
    text = capsys.readouterr().out
    for word in ("simulate.csv", "loop.png", "simulate.json", "--thresholds", "example:"):
        assert word in text


def test_top_level_help_lists_commands_and_missing_command_exits_2(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--help"])
    assert exc.value.code == 0
    text = capsys.readouterr().out
    assert "simulate" in text and "Exit codes" in text
    with pytest.raises(SystemExit) as exc:
        main([])
    assert exc.value.code == 2
    assert "piest: error: " in capsys.readouterr().err


def test_a_model_file_runs_as_it_is(tmp_path, capsys):
    import piest_jax as pj

    pi = pj.PIOperator([0.0, 1.0, 2.0], [1.0, 0.5, 0.25], 0.2)
    m = pj.HysteresisModel(pi, pj.Creep([0.05], [0.4], 1e-3), -0.3)
    path = pj.save_model(tmp_path / "m.json", m)
    out_dir = tmp_path / "sim"
    code, _, err = _run(capsys, "--model", str(path), "--out", str(out_dir), "--quiet")
    assert code == 0, err
    rec = load_record(out_dir / "simulate.csv")
    # The plays and the lag (at rest at the first input) against NumPy references.
    lag = reference_lags(rec.u, [0.05], 1e-3, rec.u[0])[:, 0]
    np.testing.assert_allclose(
        rec.y, ref.pi(rec.u, [0.0, 1.0, 2.0], [1.0, 0.5, 0.25], 0.2) + 0.4 * lag - 0.3, atol=1e-10
    )
    summary = json.loads((out_dir / "simulate.json").read_text())
    assert summary["structure"] == "pi+creep" and summary["model"] == str(path)
    # Operator options do not mix with a model, nor a sampling interval other than the creep's.
    code, _, err = _run(capsys, "--model", str(path), "--weights", "1,2,3", "--out", str(tmp_path / "b"))
    assert code == 2 and "--weights describes a PI operator" in err
    code, _, err = _run(capsys, "--model", str(path), "--dt", "0.01", "--out", str(tmp_path / "c"))
    assert code == 2 and "was identified at dt = 0.001; sample it every 0.001" in err
