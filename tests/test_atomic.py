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

from piest_jax import _io
from piest_jax._cli import COMMANDS, main

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
    files = _tree(out)
    assert names[where] not in files
    assert not [n for n in files if n.endswith(".tmp")]  # the temporary was removed
    for name in files:  # what was written before the interruption is complete
        assert name in ("simulate.csv", "loop.png")


def test_interrupted_force_run_keeps_the_previous_results(tmp_path, capsys, monkeypatch):
    out = tmp_path / "o"
    assert _sim(capsys, out)[0] == 0
    before = _tree(out)
    monkeypatch.setattr(np, "savetxt", _interrupt_after(10))
    code, _ = _sim(capsys, out, "--force", "--amplitude", "3")
    assert code == 130
    assert _tree(out) == before


def test_writers_are_atomic_on_any_exception(tmp_path):
    p = tmp_path / "r.json"
    _io.write_json(p, {"a": 1})
    with pytest.raises(RuntimeError):
        _io._atomic_write(p, _interrupt_after(3, RuntimeError("disk full")))
    assert json.loads(p.read_text()) == {"a": 1}
    assert [q.name for q in tmp_path.iterdir()] == ["r.json"]


def test_nan_becomes_null_and_json_stays_strict(tmp_path):
    p = _io.write_json(tmp_path / "r.json", {"x": np.array([1.0, np.nan, np.inf]), "y": np.float32(2)})
    assert json.loads(p.read_text(), parse_constant=lambda c: pytest.fail(c)) == {"x": [1.0, None, None], "y": 2.0}


_KILLED_WRITER = textwrap.dedent(
    """
    import os, signal, sys
    from piest_jax import _io
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
        capture_output=True, text=True, timeout=300,
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
