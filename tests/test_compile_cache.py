"""The `piest` console script keeps compiled programs across runs (JAX's persistent compilation
cache), in the user's cache folder unless `PIEST_COMPILE_CACHE` says otherwise; a run that finds
them compiles nothing new and writes the same results; a signal leaves no entry of its own."""

import json
import os
import re
import signal
import subprocess
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import piest_jax as pj
from piest_jax._cli import compile_cache

pytestmark = pytest.mark.long

_SIM = ["simulate", "--input", "triangle", "--thresholds", "0,0.5,1", "--weights", "1,0.5,0.25", "--quiet"]


def test_the_folder_follows_the_variable(tmp_path):
    home = {"XDG_CACHE_HOME": str(tmp_path / "xdg")}
    if sys.platform.startswith("linux"):
        assert compile_cache.cache_folder(home) == tmp_path / "xdg" / "piest_jax" / "compiled"
    for off in ("off", "0", "No", " false "):
        assert compile_cache.cache_folder({**home, "PIEST_COMPILE_CACHE": off}) is None
    chosen = {**home, "PIEST_COMPILE_CACHE": str(tmp_path / "mine")}
    assert compile_cache.cache_folder(chosen) == tmp_path / "mine"


def test_enable_sets_jax_variables_and_respects_the_users(tmp_path):
    env = {"PIEST_COMPILE_CACHE": str(tmp_path / "c")}
    assert compile_cache.enable(env) == tmp_path / "c"
    assert (tmp_path / "c").is_dir()
    assert env["JAX_COMPILATION_CACHE_DIR"] == str(tmp_path / "c")
    assert env["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"] == "0"
    # A cache the user configured for JAX is theirs: nothing changes.
    users = {"JAX_COMPILATION_CACHE_DIR": str(tmp_path / "theirs"), "PIEST_COMPILE_CACHE": str(tmp_path / "c2")}
    assert compile_cache.enable(users) == tmp_path / "theirs"
    assert "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS" not in users
    assert not (tmp_path / "c2").exists()
    # Off, or a folder that cannot be made: no cache, and the command still runs.
    off = {"PIEST_COMPILE_CACHE": "off"}
    assert compile_cache.enable(off) is None and "JAX_COMPILATION_CACHE_DIR" not in off
    (tmp_path / "file").write_text("x")
    blocked = {"PIEST_COMPILE_CACHE": str(tmp_path / "file" / "sub")}
    assert compile_cache.enable(blocked) is None and "JAX_COMPILATION_CACHE_DIR" not in blocked


def _piest(args, env, cwd):
    return subprocess.run(
        [sys.executable, "-m", "piest_jax", *args], env=env, cwd=cwd, capture_output=True, text=True, timeout=600
    )


def _env(tmp_path, **extra):
    env = {k: v for k, v in os.environ.items() if not k.startswith(("JAX_", "PIEST_"))}
    return {
        **env,
        "MPLBACKEND": "Agg",
        "HOME": str(tmp_path / "home"),
        "XDG_CACHE_HOME": str(tmp_path / "xdg"),
        **extra,
    }


_MAP = ["montecarlo", "--inputs", "14", "--samples", "300", "--plays", "3", "--seed", "0", "--quiet"]


def _without_timing(x):
    """A report without its wall-clock `seconds` fields."""
    return {k: _without_timing(v) for k, v in x.items() if k != "seconds"} if isinstance(x, dict) else x


def _write(path, t, u, y):
    np.savetxt(path, np.column_stack([t, u, y]), delimiter=",", header="t,u,y", comments="")


def _diagnose_args(folder) -> list[str]:
    """`diagnose` on a small record with creep, validated on a second: the joint refinement, the
    validation from an input history and the standard errors all run."""
    for name, seed in (("ident.csv", 0), ("val.csv", 1)):
        rec, _ = pj.hidden_effect_record(("creep",), key=jax.random.PRNGKey(seed), n_samples=300)
        _write(folder / name, rec.t, rec.u, rec.y)
    return ["diagnose", "ident.csv", "--validate", "val.csv", "--candidates", "creep,delay", "--quiet"]


def _record_and_model(folder):
    """A small record through a PI operator with creep, and that model as a model file."""
    model = pj.HysteresisModel(
        pj.PIOperator(jnp.array([0.0, 0.4, 0.9]), jnp.array([1.0, 0.5, 0.3])), pj.Creep([0.05, 2.0], [0.2, -0.1], 1e-3)
    )
    t = np.arange(600) * 1e-3
    u = 1.5 * np.sin(2 * np.pi * 4 * t)
    _write(folder / "r.csv", t, u, np.asarray(model(jnp.asarray(u))))
    pj.save_model(folder / "m.json", model)


def _estimate_args(folder) -> list[str]:
    _record_and_model(folder)
    return ["estimate", "r.csv", "--quiet"]


def _compensate_args(folder) -> list[str]:
    _record_and_model(folder)
    return ["compensate", "m.json", "r.csv", "--column", "y", "--quiet"]


# `reproduce` runs the paper's figure through programs whose inputs are checked before them, the
# map's program leaves out the check of its drawn inputs, and the diagnosis's refinement the
# checks of its plays (their inputs finite by construction): a check of a traced value would be a
# host callback, which JAX does not keep.
@pytest.mark.parametrize(
    ("args", "results"),
    [
        (_SIM, ["simulate.json", "simulate.csv"]),
        (["reproduce", "fig5"], ["fig5.json"]),
        (_MAP, ["pe_map.json"]),
        (_estimate_args, ["estimate.json"]),
        (_compensate_args, ["compensate.json"]),
        (_diagnose_args, ["report.json"]),
    ],
    ids=["simulate", "reproduce", "montecarlo", "estimate", "compensate", "diagnose"],
)
def test_a_second_run_finds_every_program_and_writes_the_same(tmp_path, args, results):
    if callable(args):
        args = args(tmp_path)
    env = _env(tmp_path)
    first = _piest([*args, "--out", "a"], env, tmp_path)
    assert first.returncode == 0, first.stderr
    folder = tmp_path / "xdg" / "piest_jax" / "compiled"
    entries = set(os.listdir(folder))
    assert entries
    assert first.stderr == ""
    second = _piest([*args, "--out", "b"], {**env, "JAX_LOG_COMPILES": "1"}, tmp_path)
    assert second.returncode == 0, second.stderr
    # Everything the second run compiled was already there: no new entry, and every program it
    # compiled was read from the cache (a program JAX does not keep is compiled again unseen).
    assert set(os.listdir(folder)) == entries
    # Every compilation line counts, whatever the program's name, against every cache hit.
    compiled = re.findall(r"^Compiling (.*?) with ", second.stderr, re.M)
    found = re.findall(r"^Persistent compilation cache hit for '(.*?)'", second.stderr, re.M)
    assert compiled and len(compiled) == len(found), (sorted(compiled), sorted(found))
    for name in results:
        a, b = (tmp_path / d / name for d in "ab")
        if name.endswith(".json"):
            assert _without_timing(json.loads(a.read_text())) == _without_timing(json.loads(b.read_text()))
        else:
            assert a.read_bytes() == b.read_bytes()


def test_off_writes_no_cache(tmp_path):
    proc = _piest([*_SIM, "--out", "a"], _env(tmp_path, PIEST_COMPILE_CACHE="off"), tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert not (tmp_path / "xdg" / "piest_jax").exists()
    assert not list(tmp_path.glob("home/**/piest_jax"))


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")
def test_a_signal_removes_the_entries_of_the_run(tmp_path):
    folder = tmp_path / "cache"
    env = _env(tmp_path, PIEST_COMPILE_CACHE=str(folder))
    args = ["montecarlo", "--inputs", "4000", "--samples", "20000", "--out", "mc"]
    proc = subprocess.Popen([sys.executable, "-m", "piest_jax", *args], env=env, cwd=tmp_path, stderr=subprocess.PIPE)
    seen: set[str] = set()
    deadline = time.monotonic() + 300
    while not seen and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
        seen = set(os.listdir(folder)) if folder.is_dir() else set()
    assert seen and proc.poll() is None, "the run ended before it wrote an entry"
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 128 + signal.SIGTERM
    assert err.decode().strip() == "piest montecarlo: terminated"
    assert not (seen & set(os.listdir(folder)))
    assert not (tmp_path / "mc").exists()


def test_jax_keeps_no_program_with_a_check_of_a_traced_value(tmp_path):
    # What docs/performance.md says of the programs a second run compiles again.
    script = """
import equinox as eqx, jax, jax.numpy as jnp
def plain(a):
    return jnp.sin(a) * 2.0
def checked(a):
    return eqx.error_if(a, jnp.any(a < 0), "negative") * 3.0
x = jnp.arange(3.0)
jax.jit(plain)(x).block_until_ready()
jax.jit(checked)(x).block_until_ready()
"""
    env = _env(tmp_path, JAX_COMPILATION_CACHE_DIR=str(tmp_path / "c"), JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS="0")
    proc = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    names = os.listdir(tmp_path / "c")
    assert any(n.startswith("jit_plain-") for n in names)
    assert not any(n.startswith("jit_checked-") for n in names)
