"""Compiled programs kept across `piest` runs: JAX's persistent compilation cache.

Each `piest` process compiles its XLA programs afresh, up to two fifths of a short command's
time (`experiments/bench_cold_start.py`, docs/performance.md). The console script therefore
points JAX's persistent compilation cache at a folder of the user's cache directory, so that a
second run of a command loads what the first compiled. Only the console script does this
(`interrupt.entry`), before JAX is imported: `run_cli` inside someone else's program leaves
their JAX configuration alone.

`PIEST_COMPILE_CACHE` chooses: unset, the user's cache folder (`cache_folder`); `off` (or `0`,
`no`, `false`), no cache; anything else, that folder. A cache the user set up for JAX
(`JAX_COMPILATION_CACHE_DIR`) is left as it is. A folder that cannot be created turns the cache
off rather than failing the command: it only saves time. JAX keeps no program that calls back
into Python, which every `eqx.error_if` check of a traced value does; those compile on every run.
"""

import os
import sys
import warnings
from pathlib import Path

ENV = "PIEST_COMPILE_CACHE"
_OFF = {"off", "0", "no", "false"}
# The folder this process writes to and the entries it held before (see `discard_new`).
_STATE: dict = {}


def user_cache_home(environ=None) -> Path:
    """The platform's folder for a user's caches (XDG on Linux, Library/Caches on macOS)."""
    env = os.environ if environ is None else environ
    if sys.platform == "win32":
        return Path(env.get("LOCALAPPDATA") or Path.home() / "AppData" / "Local")
    if sys.platform == "darwin":
        return Path.home() / "Library" / "Caches"
    return Path(env.get("XDG_CACHE_HOME") or Path.home() / ".cache")


def cache_folder(environ=None) -> Path | None:
    """Where `piest` keeps compiled programs, from `PIEST_COMPILE_CACHE` (None: off)."""
    env = os.environ if environ is None else environ
    value = env.get(ENV, "").strip()
    if value.lower() in _OFF:
        return None
    if value:
        return Path(value).expanduser().absolute()
    return user_cache_home(env) / "piest_jax" / "compiled"


def enable(environ=None) -> Path | None:
    """Point JAX's persistent compilation cache at `cache_folder()`; the folder used, or None.

    Through JAX's environment variables, read when JAX is imported, so that `piest --help` still
    answers without importing it. Every program is kept, however quickly it compiled: a command
    compiles hundreds of small programs, and together they are what a second run saves (JAX's
    default keeps only those that took a second or more).
    """
    env = os.environ if environ is None else environ
    if env.get("JAX_COMPILATION_CACHE_DIR"):
        return Path(env["JAX_COMPILATION_CACHE_DIR"])
    folder = cache_folder(env)
    if folder is None:
        return None
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    if not os.access(folder, os.W_OK):
        return None
    env["JAX_COMPILATION_CACHE_DIR"] = str(folder)
    env.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")
    env.setdefault("JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES", "0")
    _STATE.update(folder=folder, before=_entries(folder))
    # JAX writes an entry in place, so a process killed outright (SIGKILL, power loss) can leave
    # one cut short; JAX then warns on every read of it and compiles afresh. The compilation is
    # what the cache saves, never a result, so the warning would only alarm.
    warnings.filterwarnings("ignore", message="Error reading persistent compilation cache entry")
    return folder


def _entries(folder: Path) -> set[str]:
    try:
        return set(os.listdir(folder))
    except OSError:
        return set()


def discard_new() -> None:
    """Remove the entries added to the folder since this process started: called when a signal
    ends it, since JAX writes an entry in place and one being written at that moment would be
    left cut short. Another run's new entries go too, which costs that program a compilation."""
    folder = _STATE.get("folder")
    if folder is None:
        return
    for name in _entries(folder) - _STATE["before"]:
        try:
            os.unlink(folder / name)
        except OSError:
            pass
