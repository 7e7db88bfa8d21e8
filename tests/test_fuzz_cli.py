"""Every `piest` command on hostile input: exit code 2, one line on stderr naming the file, the row
and the problem, nothing on stdout, nothing written, never a traceback.

Commands run in-process through `piest_jax._cli.main`; one test runs the installed `piest` script
in a subprocess to prove the real entry point behaves the same.
"""

import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from piest_jax import _diagnose
from piest_jax._cli import COMMANDS, build_parser, main

import reference as ref

NAMES = [m.NAME for m in COMMANDS]


def _subparsers():
    action = next(a for a in build_parser()._actions if a.dest == "command")
    return action.choices


def _data_argv(name):
    """How a command takes one data file, or None when it takes none."""
    if name == "simulate":
        return lambda f: ["--input", "csv", "--csv", f]
    sub = _subparsers()[name]
    pos = [a for a in sub._actions if not a.option_strings and a.dest != "help"]
    if pos and all(a.choices is None for a in pos):
        first = pos[0]
        if len(pos) == 1 and (first.dest == "data" or ".csv" in str(first.metavar).lower()):
            return lambda f: [f]
    return None


DATA_COMMANDS = [n for n in NAMES if _data_argv(n) is not None]


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
        ("gap", "t,u,y\n" + "".join(f"{float(a + (a > 1) * 0.5)!r},{float(b)!r},{float(c)!r}\n" for a, b, c in zip(t, u, y)),
         "row 103: non-uniform sampling"),
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
    return d


@pytest.mark.parametrize("command", DATA_COMMANDS)
def test_bad_data_files_give_one_line_and_write_nothing(command, bad_dir, tmp_path, capsys):
    argv = _data_argv(command)
    for name, _, needle in BAD:
        path = str(bad_dir / f"{name}.csv")
        out = tmp_path / name
        code, o, err = _run(capsys, [command, *argv(path), "--out", str(out)])
        _assert_one_line_error(code, o, err, path, needle)
        assert not out.exists() or not any(out.iterdir()), name


@pytest.mark.parametrize("command", DATA_COMMANDS)
def test_missing_file_and_folder(command, tmp_path, capsys):
    argv = _data_argv(command)
    for path, needle in [(tmp_path / "absent.csv", "no such file"), (tmp_path, "is a folder")]:
        code, o, err = _run(capsys, [command, *argv(str(path)), "--out", str(tmp_path / "o")])
        _assert_one_line_error(code, o, err, str(path), needle)


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
        code, o, err = _run(capsys, ["simulate", "--input", "csv", "--csv", str(src), "--out", str(out),
                                     "--thresholds", "0,0.25,0.5", "--weights", "1,0.5,0.25"])
        assert code == 0, err
        data = np.loadtxt(out / "simulate.csv", delimiter=",", skiprows=1)
        np.testing.assert_array_equal(data[:, 1], u)
        np.testing.assert_allclose(data[:, 2], ref.pi(u, r, w), rtol=1e-12, atol=1e-12 * np.abs(u).max())


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


def _options(name):
    sub = _subparsers()[name]
    return sorted(s for a in sub._actions for s in a.option_strings if s not in ("-h", "--help"))


_VALUES = st.sampled_from(["nan", "inf", "-inf", "-1", "0", "1e308", "1e-320", "", "abc", "1,,2", "3", "0,1", "--"])


@pytest.mark.parametrize("command", NAMES)
@settings(max_examples=40, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_argument_fuzz_parses_or_fails_in_one_line(command, data, capsys):
    opts = _options(command)
    argv = [command]
    for _ in range(data.draw(st.integers(0, 4))):
        argv.append(data.draw(st.sampled_from(opts)))
        argv.append(data.draw(_VALUES))
    try:
        build_parser().parse_args(argv)
    except SystemExit as e:
        err = capsys.readouterr().err
        assert e.code == 2
        assert err.count("\n") == 1 and "error: " in err and "Traceback" not in err, err


def test_the_installed_piest_script_fails_in_one_line(tmp_path):
    script = shutil.which("piest", path=str(Path(sys.executable).parent)) or shutil.which("piest")
    assert script, "the `piest` console script is not installed"
    bad = tmp_path / "scope export.csv"
    bad.write_text("Instrument X\nt,u,y\n0,1,2\n0.1,oops,3\n")
    proc = subprocess.run(
        [script, "simulate", "--input", "csv", "--csv", str(bad), "--out", str(tmp_path / "o")],
        capture_output=True, text=True, timeout=300,
    )
    assert proc.returncode == 2
    assert proc.stdout == ""
    assert proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr
    assert f"{bad}, row 4: cell 2 is not a number: 'oops' (column `u`)" in proc.stderr
