"""SIGTERM (`kill`) and SIGINT (Ctrl-C) end every `piest` command within 2 s, mid-computation,
with exit 143 / 130, one line on stderr, no traceback, and nothing written or half-written.

Each command runs in a subprocess through the console script's entry on a job long enough to be
still computing (compiled XLA code, the play kernel, Python loops over candidates, a CSV being
written); a wrapper prints a marker line when the computation starts, and the signal follows.
Both signals are sent to two processes running side by side, so a test costs one start-up.
"""

import json
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

pytestmark = pytest.mark.long

# Where each command's computation starts (module, attribute), and a job that runs for a while.
_JOBS = {
    "simulate": (
        "piest_jax._cli.simulate",
        "_io.write_csv",
        ["simulate", "--plays", "400", "--r-max", "5", "--duration", "100"],
    ),
    "fit": ("piest_jax._identification.identify", "select_model", ["fit", "{rec}", "--starts", "8"]),
    "diagnose": ("piest_jax._diagnosis.diagnose", "diagnose", ["diagnose", "{rec}"]),
    "compensate": ("piest_jax._cli.compensate", "feedforward", ["compensate", "{model}", "{rec}"]),
    "montecarlo": ("piest_jax._cli.montecarlo", "pe_map", ["montecarlo", "--inputs", "4000", "--samples", "20000"]),
    "reproduce": ("piest_jax._cli.reproduce", "reproduce", ["reproduce", "all"]),
    "estimate": ("piest_jax._estimation.online", "estimate_record", ["estimate", "{rec}", "--plays", "400"]),
    "excite": (
        "piest_jax._cli.excite",
        "design_input",
        ["excite", "--thresholds", "0,0.5,1,1.5,2", "--amplitude", "3", "--samples", "3000000"],
    ),
}


def test_every_command_has_a_job():
    from piest_jax._cli import COMMANDS

    assert {m.NAME for m in COMMANDS} == set(_JOBS)


_WRAPPER = textwrap.dedent(
    """
    import importlib, signal, sys
    # A shell's background job starts with SIGINT ignored, which this child would inherit.
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    module, attr, argv = sys.argv[1], sys.argv[2], sys.argv[3:]
    owner = importlib.import_module(module)
    *path, name = attr.split(".")
    for p in path:
        owner = getattr(owner, p)
    real = getattr(owner, name)

    def marked(*args, **kwargs):
        sys.stderr.write("computing\\n")
        sys.stderr.flush()
        return real(*args, **kwargs)

    setattr(owner, name, marked)
    sys.argv = ["piest", *argv]
    from piest_jax._cli import entry
    entry()
    """
)


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    d = tmp_path_factory.mktemp("long")
    t = 1e-3 * np.arange(60_000)
    u = 2 * np.sin(2 * np.pi * t) * (1 + 0.4 * np.sin(2 * np.pi * 0.07 * t))
    y = u + 0.3 * np.sin(2 * np.pi * t + 0.5) + 0.01 * np.cos(37 * t)
    np.savetxt(d / "rec.csv", np.c_[t, u, y], delimiter=",", header="t,u,y", comments="")
    n = 20_000
    r = np.linspace(0, 2, n, endpoint=False)
    (d / "model.json").write_text(
        json.dumps(
            {"thresholds": r.tolist(), "weights": [1.0] + [1e-4] * (n - 1), "offset": 0.0, "initial_states": [0.0] * n}
        )
    )
    (d / "wrapper.py").write_text(_WRAPPER)
    return d


def _start(inputs, command, out, extra=()):
    module, attr, argv = _JOBS[command]
    argv = [a.format(rec=inputs / "rec.csv", model=inputs / "model.json") for a in argv]
    return subprocess.Popen(
        [sys.executable, str(inputs / "wrapper.py"), module, attr, *argv, "--out", str(out), "--quiet", *extra],
        # No `preexec_fn`: it runs the parent's fork hooks, and JAX's warns (an error here) once
        # JAX runs threads in this test process.
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _signal_mid_computation(proc, sig):
    line = proc.stderr.readline()
    assert line == "computing\n", line + proc.stderr.read()
    time.sleep(0.3)  # well inside the computation
    assert proc.poll() is None, "the job ended before the signal"
    sent = time.monotonic()
    proc.send_signal(sig)
    out, err = proc.communicate(timeout=60)
    return proc.returncode, time.monotonic() - sent, out, err


@pytest.mark.parametrize("command", list(_JOBS))
def test_signals_end_every_command_at_once(command, inputs, tmp_path):
    procs = {sig: _start(inputs, command, tmp_path / sig.name) for sig in (signal.SIGTERM, signal.SIGINT)}
    try:
        for sig, proc in procs.items():
            code, elapsed, out, err = _signal_mid_computation(proc, sig)
            word = "terminated" if sig == signal.SIGTERM else "interrupted"
            assert (code, out, err) == (128 + sig, "", f"piest {command}: {word}\n")
            assert elapsed < 2.0, (sig.name, elapsed)
            out_dir = tmp_path / sig.name
            # Nothing written, no temporary left, and the folder the run created is gone.
            assert not out_dir.exists(), sorted(p.name for p in out_dir.iterdir())
    finally:
        for proc in procs.values():
            if proc.poll() is None:
                proc.kill()
                proc.wait()


def test_a_signal_keeps_the_previous_results_intact(inputs, tmp_path):
    out = tmp_path / "o"
    out.mkdir()
    before = {n: f"earlier {n}\n" for n in ("simulate.csv", "loop.png", "simulate.json")}
    for n, text in before.items():
        (out / n).write_text(text)
    proc = _start(inputs, "simulate", out, ["--force"])
    code, elapsed, _, err = _signal_mid_computation(proc, signal.SIGTERM)
    assert code == 143 and elapsed < 2.0, err
    # The CSV was being written (to a temporary) when the signal came: the old set is untouched.
    assert {p.name: p.read_text() for p in out.iterdir()} == before
