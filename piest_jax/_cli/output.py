"""Writing results so that an interrupted or failed run never leaves a half-written file or a
half-replaced set of files.

Every file is written to a hidden temporary name in its destination folder and renamed into place,
which is atomic on POSIX file systems. Inside an [`output_transaction`][] (every `piest` command
runs in one) the renames wait until the command has succeeded and then happen together, so the
output folder holds either the previous complete set of results or the new complete set.
"""

import contextlib
import contextvars
import errno
import os
import signal
import socket
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from .._report import NonFiniteError as NonFiniteError
from .._report import check_finite, figure_options, json_text

# Temporaries are `.NAME.PID.RANDOM.tmp`: hidden, never mistaken for results, and the PID tells a
# later run whether the writer is gone.
_TMP_SUFFIX = ".tmp"
# Debris of a killed writer is removed only after this long, so a slow writer on another machine
# sharing the folder is never disturbed.
_DEBRIS_AGE_S = 3600.0
# One run writes into an output folder at a time: it holds this file there (its PID and host).
LOCK_NAME = ".piest.lock"
# Held while a commit renames files; `discard_temporaries` (a signal's last act) waits for it.
COMMIT_LOCK = threading.Lock()
# Every folder this process has written a temporary into, and the transactions open now: what a
# signal's watcher thread (`interrupt.py`) cleans up. (The context variable is per thread.)
_FOLDERS: set[Path] = set()
_OPEN: list["OutputTransaction"] = []


class OutputTransaction:
    """The files of one run, staged under temporary names and renamed into place together.

    Create it with [`output_transaction`][]; the writers of this module stage into the active one.
    """

    def __init__(self, nonfinite=(), outputs=()):
        self.nonfinite = frozenset(nonfinite)
        self.outputs = tuple(outputs)
        self._staged: dict[Path, str] = {}
        self._stale: list[Path] = []
        self._created: list[Path] = []
        self._locks: list[Path] = []

    def release(self) -> None:
        """Remove the output folders' locks this run holds."""
        for lock in self._locks:
            _unlink(lock)
        self._locks = []

    def stage(self, path: Path, write) -> Path:
        """Write `path`'s new contents to a temporary file; it appears at `commit`."""
        path = Path(path)
        if path.is_dir():
            raise IsADirectoryError(f"{path} is a folder; cannot write a result there")
        tmp = _write_temporary(path, write)
        old = self._staged.pop(path, None)
        if old is not None:  # written twice in one run: the last version wins
            _unlink(old)
        self._staged[path] = tmp
        return path

    def commit(self) -> None:
        """Rename every staged file into place (and remove this command's results of an earlier
        run that this run did not rewrite), shielded from Ctrl-C and `kill`."""
        with COMMIT_LOCK, _signals_deferred():
            staged, self._staged = self._staged, {}
            stale = [p for p in self._stale if p not in staged]
            self._stale, self._created = [], []
            try:
                for path, tmp in staged.items():
                    os.replace(tmp, path)
                for p in stale:
                    _unlink(p)
            finally:
                for tmp in staged.values():  # left only if a rename failed
                    _unlink(tmp)
            for folder in {p.parent for p in staged}:
                _fsync_folder(folder)

    def abort(self) -> None:
        """Drop every staged file; remove folders this run created if they are still empty."""
        for tmp in self._staged.values():
            _unlink(tmp)
        self._staged, self._stale = {}, []
        self.release()
        for folder in reversed(self._created):
            with contextlib.suppress(OSError):
                folder.rmdir()
        self._created = []


_ACTIVE: contextvars.ContextVar[OutputTransaction | None] = contextvars.ContextVar(
    "piest_output_transaction", default=None
)


@contextlib.contextmanager
def output_transaction(*, nonfinite=(), outputs=()):
    """Make every file written inside the block appear together when the block succeeds.

    **Arguments:** `nonfinite`, names of JSON keys (or CSV columns) whose values may legitimately
    be infinite or NaN (written as `null` and listed under the report's `"non_finite"` key); any
    other non-finite number fails the run with [`NonFiniteError`][]. `outputs`, every file name the
    command can write: with `--force`, ones that an earlier run left and this run does not
    rewrite are removed at commit, so the folder never mixes two runs.

    **Returns:** a context manager yielding the [`OutputTransaction`][]. On an exception
    (Ctrl-C included) nothing is renamed: the previous results stay as they were and the
    temporaries are removed.
    """
    tx = OutputTransaction(nonfinite, outputs)
    token = _ACTIVE.set(tx)
    _OPEN.append(tx)
    try:
        yield tx
    except BaseException:
        tx.abort()
        raise
    else:
        tx.commit()
    finally:
        tx.release()
        _OPEN.remove(tx)
        _ACTIVE.reset(token)


def discard_temporaries() -> None:
    """Remove every temporary file this process has written and not yet renamed, and the empty
    folders its open transactions created: what is left to do before the process ends at once
    on a signal (see `interrupt.py`). Files are found by this process's id in their names, so
    one whose writing has only begun goes too."""
    pid = os.getpid()
    for folder in list(_FOLDERS):
        with contextlib.suppress(OSError):
            for p in folder.glob(f".*.{pid}.*{_TMP_SUFFIX}"):
                _unlink(p)
    for tx in list(_OPEN):
        tx.release()
        for folder in reversed(tx._created):
            with contextlib.suppress(OSError):
                folder.rmdir()


@contextlib.contextmanager
def _signals_deferred():
    # The renames take microseconds; a Ctrl-C or kill arriving meanwhile is noted and delivered
    # right after them, so the folder never holds half of the new set. (Blocking the signals
    # would not do: any of the process's other threads may receive them.)
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    pending: list[int] = []
    previous = {}
    for sig in (signal.SIGINT, signal.SIGTERM):
        previous[sig] = signal.signal(sig, lambda signum, frame: pending.append(signum))
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler if handler is not None else signal.SIG_DFL)
        for signum in dict.fromkeys(pending):
            signal.raise_signal(signum)


def _unlink(path) -> None:
    with contextlib.suppress(FileNotFoundError):
        os.unlink(path)


def _fsync_folder(folder: Path) -> None:
    # Makes the renames durable; not every platform or file system can open a folder.
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _umask() -> int:
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)  # elsewhere the only way to read it is to set it
    os.umask(mask)
    return mask


def _write_temporary(path: Path, write) -> str:
    _FOLDERS.add(path.parent.absolute())
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.{os.getpid()}.", suffix=_TMP_SUFFIX, dir=path.parent)
    except OSError as e:
        raise _named(e, path) from None
    try:
        with os.fdopen(fd, "wb") as f:
            # mkstemp makes the file private (rw-------); results get the permissions any other
            # file the user creates gets.
            if hasattr(os, "fchmod"):
                os.fchmod(f.fileno(), 0o666 & ~_umask())
            write(f)
            f.flush()
            os.fsync(f.fileno())
    except OSError as e:
        _unlink(tmp)
        raise _named(e, path) from None
    except BaseException:
        _unlink(tmp)
        raise
    return tmp


def _named(e: OSError, path: Path) -> OSError:
    # The error names the result the user asked for, not the hidden temporary file.
    return OSError(f"{path}: cannot write it ({e.strerror or e}); nothing was written")


def _atomic_write(path: Path, write) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tx = _ACTIVE.get()
    if tx is not None:
        return tx.stage(path, write)
    tmp = _write_temporary(path, write)
    try:
        os.replace(tmp, path)
    except BaseException:
        _unlink(tmp)
        raise
    return path


def write_json(path, obj) -> Path:
    """Write `obj` as indented, strict JSON, atomically.

    Arrays become lists. JSON has no NaN or infinity: a non-finite number is written as `null`
    and its location and value are listed under the top-level key `"non_finite"` (for example
    `{"sweep.time_to_1pct[0]": "inf"}`). Inside a command's [`output_transaction`][] only the
    keys it declares may hold one: any other non-finite number raises [`NonFiniteError`][] and
    nothing is written. Outside a transaction (library use) every one is written and flagged.

    **Arguments:** `path`, the destination; `obj`, nested dicts/lists of numbers, strings, arrays.

    **Returns:** the path written.
    """
    path = Path(path)
    tx = _ACTIVE.get()
    text = json_text(obj, name=path.name, allowed=None if tx is None else tx.nonfinite)
    return _atomic_write(path, lambda f: f.write(text.encode()))


def write_text(path, text: str) -> Path:
    """Write a text file atomically. **Returns:** the path written."""
    return _atomic_write(Path(path), lambda f: f.write(text.encode()))


def write_csv(path, columns: dict) -> Path:
    """Write equal-length columns as a CSV with a header row, atomically.

    Inside a command's [`output_transaction`][] a NaN or infinite value raises
    [`NonFiniteError`][] (unless its column is declared as allowed to hold one).

    **Arguments:** `path`; `columns`, a mapping from column name to a 1-D array.

    **Returns:** the path written.
    """
    path = Path(path)
    names = list(columns)
    data = np.column_stack([np.asarray(columns[k], dtype=np.float64) for k in names])
    tx = _ACTIVE.get()
    if tx is not None:
        bad = ~np.isfinite(data)
        # The first non-finite value of each column, as (column, row) locations.
        first = [
            ((names[j], int(np.argmax(bad[:, j]))), float(data[np.argmax(bad[:, j]), j]))
            for j in np.flatnonzero(bad.any(axis=0))
        ]
        check_finite(path.name, first, tx.nonfinite)

    def write(f):
        f.write((",".join(names) + "\n").encode())
        np.savetxt(f, data, delimiter=",", fmt="%.17g")

    return _atomic_write(path, write)


def save_figure(fig, path, **kwargs) -> Path:
    """Save a matplotlib figure atomically and close it. **Returns:** the path written."""

    path = Path(path)
    fmt, kwargs = figure_options(path, kwargs)
    try:
        return _atomic_write(path, lambda f: fig.savefig(f, format=fmt, **kwargs))
    finally:
        # Figures drawn through pyplot stay registered there until closed; others need nothing.
        if getattr(fig.canvas, "manager", None) is not None:
            import matplotlib.pyplot as plt

            plt.close(fig)


def _remove_debris(out: Path, names, locked: bool = False) -> None:
    """Remove temporaries that a killed run (`kill -9`, power loss) left for these results: those
    whose writer is gone, at once when this run holds the folder's lock (no other run writes
    there, on any host), else once they are older than `_DEBRIS_AGE_S`."""
    now = time.time()
    for name in names:
        for p in out.glob(f".{name}.*{_TMP_SUFFIX}"):
            parts = p.name[len(name) + 2 :].split(".")
            if not (len(parts) == 3 and parts[0].isdigit()):
                continue
            try:
                pid = int(parts[0])
                if _alive(pid) or (not locked and now - p.stat().st_mtime < _DEBRIS_AGE_S):
                    continue
                p.unlink()
            except OSError:
                pass


def _lock(out: Path) -> Path:
    """Take `out`'s lock for this process: `FileExistsError` naming the run that holds it; a
    lock whose process on this host is gone is taken over."""
    lock = out / LOCK_NAME
    me = f"{os.getpid()} {socket.gethostname()}\n"
    for _ in range(2):
        try:
            fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            try:
                pid_text, _, host = lock.read_text().strip().partition(" ")
            except OSError:
                pid_text, host = "", ""
            if pid_text.isdigit() and host == socket.gethostname() and not _alive(int(pid_text)):
                _unlink(lock)  # stale: its process is gone
                continue
            who = f"pid {pid_text} on {host}" if pid_text.isdigit() else "another process"
            raise FileExistsError(
                f"--out {out}: another piest run ({who}) is writing there; wait for it to end or "
                f"choose another --out (if none is running, remove {lock})"
            ) from None
        with os.fdopen(fd, "w") as f:
            f.write(me)
        return lock
    raise FileExistsError(f"--out {out}: cannot take its lock {lock}")


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # exists but belongs to someone else
        return True
    return True


def check_outputs(out_dir, names, force: bool) -> Path:
    """Refuse to overwrite existing results unless `force` is set.

    **Arguments:** `out_dir`, the output folder; `names`, the files a command will write;
    `force`, overwrite them if present.

    **Returns:** the output folder as a `Path` (created if missing; inside an
    [`output_transaction`][] removed again if the run fails and it is still empty). Raises
    `FileExistsError` naming the first existing file otherwise. Inside a transaction the
    command's other outputs (from an earlier run with other options) count as existing results
    too; with `force` they are removed when the new results land.
    """
    out = Path(out_dir)
    tx = _ACTIVE.get()
    names = list(names)
    others = [n for n in (tx.outputs if tx is not None else ()) if n not in names]
    if out.exists() and not out.is_dir():
        raise NotADirectoryError(f"--out {out} exists and is not a folder")
    for name in names + others:
        if (out / name).is_dir():
            raise IsADirectoryError(f"{out / name} is a folder; cannot write a result there")
    if not force:
        for name in names + others:
            if (out / name).exists():
                raise FileExistsError(f"{out / name} already exists; pass --force to overwrite it")
    missing = [p for p in (out, *out.parents) if not p.exists()]
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise OSError(f"--out {out}: cannot create the folder ({e.strerror or e})") from None
    if tx is not None:
        tx._created.extend(reversed(missing))
        missing = []
    # Writable? Found now, before the computation, not when the results are ready.
    _FOLDERS.add(out.absolute())
    try:
        fd, probe = tempfile.mkstemp(prefix=f".piest-probe.{os.getpid()}.", suffix=_TMP_SUFFIX, dir=out)
        os.close(fd)
        os.unlink(probe)
    except OSError as e:
        # The folder exists, so "No such file or directory" (what /proc answers) would mislead.
        why = "it takes no new files" if e.errno == errno.ENOENT else (e.strerror or e)
        raise OSError(f"--out {out}: cannot write there ({why})") from None
    locked = False
    if tx is not None:
        if out / LOCK_NAME not in tx._locks:
            tx._locks.append(_lock(out))
        locked = True
        tx._stale.extend(out / n for n in others if (out / n).exists())
    _remove_debris(out, names + others, locked)
    return out
