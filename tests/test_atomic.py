"""Nothing lost or half-written: results go to a temporary file renamed into place, so an
interrupted run (Ctrl-C, SIGTERM, SIGKILL) never leaves a truncated file; existing results are kept
unless --force is given; input files are never modified."""

import hashlib
import json
import os
import signal
import subprocess
import sys
import textwrap

import matplotlib.figure
import numpy as np
import pytest

from piest_jax._cli import COMMANDS, main
from piest_jax._cli import output as _io

SIM = ["--duration", "0.2", "--dt", "0.002", "--quiet"]


def _digest(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _tree(folder):
    """Every file in a folder (hidden ones included) with its hash."""
    return {p.name: _digest(p) for p in sorted(folder.iterdir())} if folder.exists() else {}


def _sim(capsys, out, *extra):
    code = main(["simulate", *SIM, "--out", str(out), *extra])
    return code, capsys.readouterr()


def _interrupt_after(n_bytes, exc=KeyboardInterrupt):
    """A writer stand-in that puts `n_bytes` of junk in the file, then raises `exc`."""

    def fail(f, *a, **k):
        f.write(b"x" * n_bytes)
        raise exc

    return fail


@pytest.mark.parametrize("where", ["csv", "png", "json"])
def test_ctrl_c_mid_write_leaves_no_file_and_no_temporary(where, tmp_path, capsys, monkeypatch):
    if where == "csv":
        monkeypatch.setattr(np, "savetxt", _interrupt_after(100))
    elif where == "png":
        monkeypatch.setattr(matplotlib.figure.Figure, "savefig", lambda self, f, **k: _interrupt_after(50)(f))
    else:
        real = _io._atomic_write

        def json_write(path, write):
            return real(path, _interrupt_after(7) if path.suffix == ".json" else write)

        monkeypatch.setattr(_io, "_atomic_write", json_write)
    out = tmp_path / "o"
    code, cap = _sim(capsys, out)
    assert code == 130
    assert cap.err == "piest simulate: interrupted\n"
    names = {"csv": "simulate.csv", "png": "loop.png", "json": "simulate.json"}
    assert names[where] in {"simulate.csv", "loop.png", "simulate.json"}
    # The outputs land together or not at all: nothing from the interrupted run is left, not
    # even the files written before the interruption, nor the temporaries, nor the folder it made.
    assert not out.exists()


def test_interrupted_force_run_keeps_the_previous_results(tmp_path, capsys, monkeypatch):
    out = tmp_path / "o"
    assert _sim(capsys, out)[0] == 0
    before = _tree(out)
    monkeypatch.setattr(np, "savetxt", _interrupt_after(10))
    code, _ = _sim(capsys, out, "--force", "--amplitude", "3")
    assert code == 130
    assert _tree(out) == before


@pytest.mark.parametrize("exc", [OSError(28, "No space left on device"), KeyboardInterrupt])
def test_a_force_run_failing_at_its_last_file_keeps_the_whole_previous_set(exc, tmp_path, capsys, monkeypatch):
    # simulate writes the CSV, then the figure, then the JSON: the first two are complete when the
    # third fails, yet none of them replaces the previous run's, and nothing new is printed.
    out = tmp_path / "o"
    assert _sim(capsys, out)[0] == 0
    before = _tree(out)
    real = _io._atomic_write

    def json_fails(path, write):
        if path.suffix == ".json":
            raise exc
        return real(path, write)

    monkeypatch.setattr(_io, "_atomic_write", json_fails)
    code, cap = _sim(capsys, out, "--force", "--amplitude", "3")
    assert code == (130 if exc is KeyboardInterrupt else 2)
    assert cap.out == ""
    assert _tree(out) == before


def test_a_signal_during_the_renames_is_delivered_after_them(tmp_path, capsys, monkeypatch):
    # Ctrl-C arriving between two renames must not leave a mix of old and new files: it is held
    # until the whole new set is in place, then reported (exit 130).
    # A shell starts background jobs (CI scripts run with `&`, `nohup`) with SIGINT ignored, and
    # the deferred signal is then rightly dropped; a terminal's Ctrl-C reaches Python's handler.
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        _signal_during_renames(tmp_path, capsys, monkeypatch)
    finally:
        signal.signal(signal.SIGINT, previous)


def _signal_during_renames(tmp_path, capsys, monkeypatch):
    out = tmp_path / "o"
    assert _sim(capsys, out)[0] == 0
    before = _tree(out)
    real = os.replace
    calls = []

    def replace(src, dst):
        real(src, dst)
        calls.append(dst)
        if len(calls) == 1:
            os.kill(os.getpid(), signal.SIGINT)

    monkeypatch.setattr(_io.os, "replace", replace)
    code, cap = _sim(capsys, out, "--force", "--amplitude", "3")
    assert code == 130 and cap.err == "piest simulate: interrupted\n"
    assert len(calls) == 3
    after = _tree(out)
    assert set(after) == set(before) and all(after[k] != before[k] for k in before)
    assert json.loads((out / "simulate.json").read_text())["input"]["amplitude"] == [3.0]


def test_a_command_s_other_outputs_from_an_earlier_run_do_not_survive_force(tmp_path):
    # `piest fit --validate` writes validation.png, a later fit without --validate does not: with
    # --force the old figure goes when the new results land (it belongs to another model), and
    # without --force it counts as an existing result.
    outputs = ("fit.json", "fit.png", "validation.png")
    with _io.output_transaction(outputs=outputs):
        out = _io.check_outputs(tmp_path / "o", outputs, force=False)
        for n in outputs:
            _io.write_text(out / n, "first\n")
    with pytest.raises(FileExistsError, match="validation.png already exists; pass --force"):
        with _io.output_transaction(outputs=outputs):
            (out / "fit.json").unlink()
            (out / "fit.png").unlink()
            _io.check_outputs(out, outputs[:2], force=False)
    # A failing --force run removes nothing; a successful one replaces the set.
    with pytest.raises(RuntimeError):
        with _io.output_transaction(outputs=outputs):
            _io.check_outputs(out, outputs[:2], force=True)
            _io.write_text(out / "fit.json", "second\n")
            raise RuntimeError("solver failed")
    assert sorted(p.name for p in out.iterdir()) == ["validation.png"]
    with _io.output_transaction(outputs=outputs):
        _io.check_outputs(out, outputs[:2], force=True)
        _io.write_text(out / "fit.json", "second\n")
        _io.write_text(out / "fit.png", "second\n")
    assert {p.name: p.read_text() for p in out.iterdir()} == {"fit.json": "second\n", "fit.png": "second\n"}


def test_a_failed_run_removes_the_folders_it_created(tmp_path):
    with pytest.raises(KeyboardInterrupt):
        with _io.output_transaction():
            out = _io.check_outputs(tmp_path / "a" / "b" / "c", ["r.json"], force=False)
            _io.write_json(out / "r.json", {"x": 1})
            raise KeyboardInterrupt
    assert list(tmp_path.iterdir()) == []
    (tmp_path / "keep").mkdir()
    (tmp_path / "keep" / "mine.txt").write_text("user data\n")
    with pytest.raises(ValueError):
        with _io.output_transaction():
            out = _io.check_outputs(tmp_path / "keep", ["r.json"], force=False)
            _io.write_json(out / "r.json", {"x": 1})
            raise ValueError
    assert [p.name for p in (tmp_path / "keep").iterdir()] == ["mine.txt"]


@pytest.mark.parametrize("mask", [0o027, 0o077, 0o002])
def test_results_get_the_permissions_of_the_user_s_umask(mask, tmp_path, capsys):
    old = os.umask(mask)
    try:
        plain = tmp_path / "plain.txt"
        with open(plain, "w") as f:
            f.write("x")
        written = [_io.write_json(tmp_path / "lib.json", {"a": 1})]
        with _io.output_transaction():
            written.append(_io.write_csv(tmp_path / "c.csv", {"a": [1.0]}))
        if mask == 0o027:  # a whole command once
            out = tmp_path / "o"
            assert _sim(capsys, out)[0] == 0
            written += list(out.iterdir())
    finally:
        os.umask(old)
    expected = 0o666 & ~mask
    assert plain.stat().st_mode & 0o777 == expected  # what a normal open() gives
    for p in written:
        assert p.stat().st_mode & 0o777 == expected, p.name


def test_debris_of_a_killed_run_is_cleaned_up_but_live_temporaries_are_not(tmp_path, capsys):
    out = tmp_path / "o"
    out.mkdir()
    dead = 2**22 + 12345  # above Linux's largest process id: no such process
    old_dead = out / f".simulate.json.{dead}.abc123.tmp"
    recent_dead = out / f".loop.png.{dead}.def456.tmp"
    old_live = out / f".simulate.csv.{os.getppid()}.ghi789.tmp"
    foreign = out / ".notes.txt.1.x.tmp"
    for p in (old_dead, recent_dead, old_live, foreign):
        p.write_text("partial")
    for p in (old_dead, old_live, foreign):
        os.utime(p, (1e9, 1e9))
    assert _sim(capsys, out)[0] == 0
    names = set(_tree(out))
    # Their writers are gone, and the run held the folder's lock (no other run wrote there): removed.
    assert old_dead.name not in names and recent_dead.name not in names
    # Still running, or not one of our results: kept. The lock went with the run.
    assert {old_live.name, foreign.name} <= names and _io.LOCK_NAME not in names
    assert {"simulate.csv", "loop.png", "simulate.json"} <= names


def test_one_run_per_output_folder(tmp_path, capsys):
    import socket

    out = tmp_path / "o"
    out.mkdir()
    lock = out / _io.LOCK_NAME
    # A live run (here the test's parent process) holds the folder: a second run refuses it.
    lock.write_text(f"{os.getppid()} {socket.gethostname()}\n")
    code, cap = _sim(capsys, out, "--force")
    assert code == 2 and cap.out == "" and cap.err.count("\n") == 1
    assert f"another piest run (pid {os.getppid()} on {socket.gethostname()}) is writing there" in cap.err
    assert set(_tree(out)) == {_io.LOCK_NAME}
    # A run on another host cannot be checked: refused too, saying how to clear it.
    lock.write_text("1 elsewhere.example\n")
    code, cap = _sim(capsys, out)
    assert code == 2 and f"remove {lock}" in cap.err
    # The lock of a process that is gone is stale: taken over, and released at the end.
    lock.write_text(f"{2**22 + 12345} {socket.gethostname()}\n")
    code, cap = _sim(capsys, out)
    assert code == 0, cap.err
    assert not lock.exists() and {"simulate.csv", "loop.png", "simulate.json"} <= set(_tree(out))
    # A refused run releases it too, and leaves no folder it created behind.
    code, cap = _sim(capsys, tmp_path / "new", "--dt", "5")
    assert code == 2 and not (tmp_path / "new").exists()


def test_writers_are_atomic_on_any_exception(tmp_path):
    p = tmp_path / "r.json"
    _io.write_json(p, {"a": 1})
    with pytest.raises(RuntimeError):
        _io._atomic_write(p, _interrupt_after(3, RuntimeError("disk full")))
    assert json.loads(p.read_text()) == {"a": 1}
    assert [q.name for q in tmp_path.iterdir()] == ["r.json"]


def test_nan_is_null_and_flagged_and_json_stays_strict(tmp_path):
    # Outside a command (library use, experiment scripts) a non-finite number is written as null
    # and listed, with its value, under "non_finite": never a silent null.
    obj = {"x": np.array([1.0, np.nan, np.inf]), "y": np.float32(2), "z": {"w": [[0.0, -np.inf]]}}
    p = _io.write_json(tmp_path / "r.json", obj)
    assert json.loads(p.read_text(), parse_constant=lambda c: pytest.fail(c)) == {
        "x": [1.0, None, None],
        "y": 2.0,
        "z": {"w": [[0.0, None]]},
        "non_finite": {"x[1]": "nan", "x[2]": "inf", "z.w[0][1]": "-inf"},
    }
    # Finite results get no such key; a bare list cannot carry the flags, so it is refused.
    assert json.loads(_io.write_json(tmp_path / "f.json", {"a": [1.5]}).read_text()) == {"a": [1.5]}
    with pytest.raises(_io.NonFiniteError, match=r"l\.json: non-finite values can only be flagged"):
        _io.write_json(tmp_path / "l.json", [1.0, np.nan])
    assert not (tmp_path / "l.json").exists()


def test_inside_a_transaction_non_finite_results_are_refused(tmp_path):
    msg = r"^the result is not finite: fit\.rmse = nan in r\.json; nothing was written$"
    with pytest.raises(_io.NonFiniteError, match=msg):
        with _io.output_transaction():
            _io.write_text(tmp_path / "a.txt", "first\n")
            _io.write_json(tmp_path / "r.json", {"fit": {"rmse": np.nan, "w": [1.0]}})
    with pytest.raises(_io.NonFiniteError, match=r"w\[1\] = inf in r\.json \(and 1 more values\)"):
        with _io.output_transaction(nonfinite=("t_hit",)):
            _io.write_json(tmp_path / "r.json", {"w": [1.0, np.inf, -np.inf], "t_hit": np.inf})
    with pytest.raises(_io.NonFiniteError, match=r"u\[2\] = -inf in c\.csv"):
        with _io.output_transaction():
            _io.write_csv(tmp_path / "c.csv", {"t": [0.0, 1.0, 2.0], "u": [1.0, 2.0, -np.inf]})
    assert sorted(tmp_path.iterdir()) == []  # nothing at all was written
    # Declared keys (and CSV columns) may hold them: null in the JSON, flagged.
    with _io.output_transaction(nonfinite=("t_hit", "v")):
        _io.write_json(tmp_path / "r.json", {"w": [1.0], "sweep": {"t_hit": [0.5, np.inf]}})
        _io.write_csv(tmp_path / "c.csv", {"t": [0.0, 1.0], "v": [np.nan, 1.0]})
    assert json.loads((tmp_path / "r.json").read_text()) == {
        "w": [1.0],
        "sweep": {"t_hit": [0.5, None]},
        "non_finite": {"sweep.t_hit[1]": "inf"},
    }
    assert (tmp_path / "c.csv").read_text() == "t,v\n0,nan\n1,1\n"


def test_a_command_with_a_non_finite_result_fails_and_writes_nothing(tmp_path, capsys, monkeypatch):
    # (A legitimately infinite value, reproduce's time never reached, is flagged instead: see
    # tests/test_determinism.py.)
    from piest_jax._cli import reproduce

    out = tmp_path / "o"
    out.mkdir()
    for name in ("fig5.json", "fig5.png"):
        (out / name).write_text("earlier result\n")
    before = _tree(out)

    def broken(report):
        return {k: v for k, v in report.items() if not k.startswith("_")} | {"final_abs_error": [0.1, np.nan, 0.2]}

    monkeypatch.setattr(reproduce, "public_report", broken)
    code = main(["reproduce", "fig5", "--out", str(out), "--force", "--P0", "1e5"])
    cap = capsys.readouterr()
    assert code == 2 and cap.out == ""  # no path is printed for a file that was not written
    assert cap.err == (
        "piest reproduce: error: the result is not finite: final_abs_error[1] = nan in fig5.json; nothing was written\n"
    )
    assert _tree(out) == before  # fig5.png, computed before the failure, did not replace the old one


_KILLED_WRITER = textwrap.dedent(
    """
    import os, signal, sys
    from piest_jax._cli import output as _io
    path, how = sys.argv[1], sys.argv[2]
    _io.write_json(path, {"run": "first", "values": list(range(50))})
    real_fsync = os.fsync

    def dies_by(sig):
        def fsync(fd):
            # The new contents are in the temporary file; the signal arrives before the rename.
            os.kill(os.getpid(), sig)
            real_fsync(fd)
        return fsync

    if how == "kill":
        _io.os.fsync = dies_by(signal.SIGKILL)
        _io.write_json(path, {"run": "second", "values": list(range(10**5))})
    else:
        # SIGTERM (plain `kill`), then SIGINT (Ctrl-C), each arriving during simulate's first write.
        from piest_jax._cli import main
        # A shell starts background jobs with SIGINT ignored, and Python then keeps it ignored;
        # a terminal's Ctrl-C reaches the usual handler, as here.
        signal.signal(signal.SIGINT, signal.default_int_handler)
        codes = []
        for sig in (signal.SIGTERM, signal.SIGINT):
            _io.os.fsync = dies_by(sig)
            codes.append(main(["simulate", "--duration", "0.05", "--quiet", "--force",
                               "--out", os.path.dirname(path)]))
        print(codes)
    """
)


def test_killed_processes_never_leave_a_truncated_result(tmp_path):
    script = tmp_path / "writer.py"
    script.write_text(_KILLED_WRITER)
    # SIGKILL cannot be caught: the old result survives intact (a stray temporary may remain).
    d1 = tmp_path / "kill"
    d1.mkdir()
    proc = subprocess.run([sys.executable, str(script), str(d1 / "r.json"), "kill"], capture_output=True, timeout=120)
    assert proc.returncode == -signal.SIGKILL
    assert json.loads((d1 / "r.json").read_text())["run"] == "first"
    # SIGTERM (plain `kill`) and SIGINT (Ctrl-C) unwind: exit 143 and 130, one line each, the
    # previous result is intact and the temporary is removed.
    d2 = tmp_path / "term"
    d2.mkdir()
    proc = subprocess.run(
        [sys.executable, str(script), str(d2 / "simulate.json"), "signals"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip().splitlines()[-1] == f"[{128 + signal.SIGTERM}, 130]"
    assert proc.stderr.strip().splitlines()[-2:] == ["piest simulate: terminated", "piest simulate: interrupted"]
    assert json.loads((d2 / "simulate.json").read_text())["run"] == "first"
    assert [p.name for p in d2.iterdir()] == ["simulate.json"]


def _command_argv(name, data, model):
    """A minimal invocation of each command (it is refused before any computation here)."""
    return {
        "simulate": ["simulate", "--input", "csv", "--csv", str(data)],
        "reproduce": ["reproduce", "fig5"],
        "montecarlo": ["montecarlo", "--inputs", "2", "--samples", "100"],
        "excite": ["excite", "--thresholds", "0,1", "--samples", "100"],
        "fit": ["fit", str(data), "--plays", "2"],
        "compensate": ["compensate", str(model), str(data)],
    }.get(name, [name, str(data)])


@pytest.mark.parametrize("command", COMMANDS, ids=lambda m: m.NAME)
def test_existing_results_are_not_overwritten_without_force(command, tmp_path, capsys):
    data = tmp_path / "d.csv"
    t = 0.01 * np.arange(300)
    data.write_text("t,u,y\n" + "".join(f"{a},{np.sin(6 * a)},{np.cos(6 * a)}\n" for a in t))
    model = tmp_path / "m.json"
    model.write_text(json.dumps({"thresholds": [0.0, 0.5], "weights": [1.0, 0.5]}))
    outputs = getattr(command, "OUTPUTS", ("fig5.json", "fig5.png"))
    if command.NAME == "fit":
        outputs = outputs[:2]  # validation.png only with --validate
    out = tmp_path / "o"
    out.mkdir()
    # Only the last output exists: the command must still refuse, before computing anything.
    (out / outputs[-1]).write_text("earlier result\n")
    before = _tree(out)
    inputs = _digest(data), _digest(model)
    code = main([*_command_argv(command.NAME, data, model), "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2
    assert err == f"piest {command.NAME}: error: {out / outputs[-1]} already exists; pass --force to overwrite it\n"
    assert _tree(out) == before
    assert (_digest(data), _digest(model)) == inputs


def test_force_overwrites_every_output_and_leaves_no_temporaries(tmp_path, capsys):
    out = tmp_path / "o"
    assert _sim(capsys, out)[0] == 0
    first = _tree(out)
    assert _sim(capsys, out)[0] == 2
    assert _tree(out) == first
    assert _sim(capsys, out, "--force", "--amplitude", "4")[0] == 0
    second = _tree(out)
    assert set(second) == set(first) == {"simulate.csv", "loop.png", "simulate.json"}
    assert all(second[k] != first[k] for k in first)
    assert json.loads((out / "simulate.json").read_text())["input"]["amplitude"] == [4.0]


def test_input_file_is_never_modified(tmp_path, capsys):
    data = tmp_path / "in.csv"
    t = 0.002 * np.arange(200)
    data.write_text("# scope\nt,u,y\n" + "".join(f"{a},{np.sin(9 * a)},0\n" for a in t))
    digest, mtime = _digest(data), data.stat().st_mtime_ns
    out = tmp_path / "o"
    assert main(["simulate", "--input", "csv", "--csv", str(data), "--out", str(out), "--quiet"]) == 0
    # Even asked to write its results over the input, it refuses.
    copy = out / "simulate.csv"
    copy_digest = _digest(copy)
    code = main(["simulate", "--input", "csv", "--csv", str(copy), "--out", str(out), "--force"])
    err = capsys.readouterr().err
    assert code == 2 and f"would overwrite the input file {copy}" in err
    assert _digest(copy) == copy_digest
    assert _digest(data) == digest and data.stat().st_mtime_ns == mtime
