"""`piest montecarlo` across processes (jax.distributed): two processes on this machine give the
single-process map draw for draw, only process 0 writes, and wrong options are refused in one
line before any process waits for another."""

import json
import os
import socket
import subprocess
import sys

import pytest

from piest_jax._cli import main

pytestmark = pytest.mark.long

# A small map: 28 draws of 300 samples, 3 plays, in chunks of 14 (7 per device on two devices).
ARGV = ["montecarlo", "--inputs", "28", "--samples", "300", "--plays", "3", "--seed", "5", "--chunk", "14"]
# A hang (a process that never joins, a collective that never completes) fails the test, not the run.
TIMEOUT_S = 240


def _env(devices: int) -> dict:
    env = dict(os.environ, JAX_PLATFORMS="cpu", XLA_FLAGS=f"--xla_force_host_platform_device_count={devices}")
    # What the processes are is given on the command line, never read from a cluster around the test.
    for name in list(env):
        if name.startswith(("SLURM_", "OMPI_", "PMI_", "JAX_COORDINATOR", "KUBERNETES_SERVICE")):
            del env[name]
    return env


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _piest(argv, devices: int) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "piest_jax", *argv, "--quiet"],
        env=_env(devices),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _finish(procs) -> list[tuple[int, str, str]]:
    """(exit code, stdout, stderr) of each process; every one is killed if any outlasts the timeout."""
    results = []
    try:
        for p in procs:
            out, err = p.communicate(timeout=TIMEOUT_S)
            results.append((p.returncode, out, err))
    except subprocess.TimeoutExpired:
        for p in procs:
            p.kill()
            p.communicate()
        pytest.fail(f"a process of the distributed map did not finish in {TIMEOUT_S} s")
    return results


def _two_processes(outs) -> list[tuple[int, str, str]]:
    """Process 0 and process 1 of one map, each with one CPU device, writing to outs[0], outs[1]."""
    coordinator = f"localhost:{_free_port()}"
    procs = [
        _piest(
            [*ARGV, "--out", str(out), "--coordinator", coordinator, "--num-processes", "2", "--process-id", str(i)], 1
        )
        for i, out in enumerate(outs)
    ]
    return _finish(procs)


def test_two_processes_give_the_single_process_map(tmp_path):
    # The reference: one process with two devices, so that every device holds the same 7 draws
    # per chunk as in the two processes below and runs the same compiled program on them.
    ((code, out, err),) = _finish([_piest([*ARGV, "--out", str(tmp_path / "one")], 2)])
    assert code == 0, err[-2000:]
    one = json.loads((tmp_path / "one" / "pe_map.json").read_text())

    outs = [tmp_path / "p0", tmp_path / "p1"]
    (code0, out0, err0), (code1, out1, err1) = _two_processes(outs)
    assert code0 == 0, err0[-2000:]
    assert code1 == 0, err1[-2000:]
    # Process 0 prints the paths it wrote and nothing else (the collectives' own chatter goes
    # to stderr); process 1 prints nothing and leaves its --out alone.
    assert out0.split() == [str(outs[0] / "pe_map.png"), str(outs[0] / "pe_map.json")]
    assert out1 == ""
    assert not outs[1].exists()
    assert (outs[0] / "pe_map.png").stat().st_size > 10_000
    two = json.loads((outs[0] / "pe_map.json").read_text())

    # Every draw the same to the last bit (JSON keeps every digit of a float64): the keys, the
    # per-device batch shapes and programs are the same, only the devices sit in two processes.
    assert two["n_inputs"] == 28 and len(two["draws"]["rho"]) == 28
    assert two["draws"] == one["draws"]
    # So is the rest of the report, but for the wall time and the devices' names.
    assert len(two["devices"]) == len(one["devices"]) == 2
    different = {k for k in one if one[k] != two.get(k)}
    assert different <= {"seconds", "devices"}, different

    # Run again into the same folders without --force: process 0 refuses its --out, and both
    # processes stop at once, exit 2, and leave the results as they were.
    before = (outs[0] / "pe_map.json").read_bytes()
    (code0, out0, err0), (code1, out1, err1) = _two_processes(outs)
    assert (code0, out0, code1, out1) == (2, "", 2, ""), (err0, err1)
    assert "piest montecarlo: error: " in err0 and "p0/pe_map.png already exists; pass --force" in err0
    assert "piest montecarlo: error: process 0 cannot write its --out" in err1
    assert "Traceback" not in err0 + err1
    assert (outs[0] / "pe_map.json").read_bytes() == before
    assert not outs[1].exists()


@pytest.mark.parametrize(
    "options, needle",
    [
        (["--coordinator", "localhost:1234"], "--coordinator given without --num-processes and --process-id"),
        (["--num-processes", "2", "--process-id", "1"], "--num-processes, --process-id given without --coordinator"),
        (
            ["--coordinator", "localhost:1234", "--num-processes", "2", "--process-id", "2"],
            "--process-id 2 is not below --num-processes 2",
        ),
        (["--distributed", "--num-processes", "2"], "--distributed takes the processes from the cluster's environment"),
        (
            ["--coordinator", "localhost", "--num-processes", "2", "--process-id", "0"],
            "argument --coordinator: expected HOST:PORT such as 10.0.0.1:1234, got 'localhost'",
        ),
        (["--coordinator", "h:99999", "--num-processes", "2", "--process-id", "0"], "expected HOST:PORT"),
        (["--coordinator", "h:1", "--num-processes", "2", "--process-id", "-1"], "argument --process-id: a process"),
        (["--coordinator", "h:1", "--num-processes", "0", "--process-id", "0"], "argument --num-processes: must be"),
    ],
)
def test_wrong_process_options_are_refused_in_one_line(options, needle, tmp_path, capsys):
    # Refused before JAX joins anything, so these run in this process.
    out = tmp_path / "o"
    try:
        code = main([*ARGV, "--out", str(out), *options])
    except SystemExit as e:  # argparse
        code = e.code
    o, err = capsys.readouterr()
    assert (code, o) == (2, ""), err
    assert err.count("\n") == 1 and err.startswith("piest montecarlo: error: "), err
    assert needle in err, err
    assert not out.exists()


def test_distributed_outside_a_cluster_is_refused_in_one_line(tmp_path):
    # In a process of its own: here JAX really looks for a cluster (and must find none).
    out = tmp_path / "o"
    ((code, o, err),) = _finish([_piest([*ARGV, "--out", str(out), "--distributed"], 1)])
    assert (code, o) == (2, ""), err
    assert err.count("\n") == 1, err
    assert err.startswith("piest montecarlo: error: --distributed: JAX read no processes from the environment"), err
    assert "give --coordinator, --num-processes and --process-id" in err
    assert not out.exists()
