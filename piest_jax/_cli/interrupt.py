"""Ending a `piest` process at once on Ctrl-C (SIGINT) or `kill` (SIGTERM).

Why not an exception, as Python does by default: Python runs a signal handler only when its main
thread next executes bytecode. A command spends its time in compiled XLA code, the play kernel or
a NumPy call on a large array, and gets back to bytecode seconds or minutes later; a handler that
raises inside a garbage-collection callback has its exception swallowed or turned into another
error; and unwinding through half-built JAX state runs finalisers that have crashed the process
(exit 139). Measured before this module: 34 s to stop a fit, 10 minutes for a compensate.

So the process entry ([`guard`][]) installs handlers whose C half (Python's own) writes the signal
number to a pipe (`signal.set_wakeup_fd`) the moment the signal arrives, and a watcher thread
blocked on that pipe acts on it. Compiled code releases the GIL, so the watcher runs within
milliseconds: it removes this process's temporary files (the transactional writer renames nothing
before the command has succeeded, so the output folder holds exactly what it held before; see
`output.discard_temporaries`), prints one line and ends the process with `os._exit(128 + signum)`,
skipping finalisers and atexit hooks, which could block or crash. A batch of renames already under
way is let to finish first (it takes microseconds), so the folder never holds half of a new set.

Only the `piest` process entry does this. `run_cli` (`main`) inside someone else's program keeps
Python's behaviour (an exception that unwinds), since ending the caller's process is not ours.
"""

import contextlib
import os
import signal
import sys
import threading

from . import compile_cache
from . import output as _io

SIGNALS = (signal.SIGINT, signal.SIGTERM)
_WORDS: dict[int, str] = {signal.SIGINT: "interrupted", signal.SIGTERM: "terminated"}
_GUARDING: list[str] = []  # non-empty while a guard is installed


def guarding() -> bool:
    """Whether a [`guard`][] is installed: signals then end the process, not unwind."""
    return bool(_GUARDING)


def _end(command: str, signum: int) -> None:
    """Remove this process's temporaries, say why in one line, and exit 128 + signum."""
    with _io.COMMIT_LOCK:  # a commit under way completes before we remove anything
        try:
            _io.discard_temporaries()
            compile_cache.discard_new()
            name = f"piest {command}" if command else "piest"
            os.write(2, f"{name}: {_WORDS.get(signum, 'stopped')}\n".encode())
        finally:
            os._exit(128 + signum)


@contextlib.contextmanager
def guard(command: str):
    """End the process within milliseconds of SIGINT or SIGTERM (see the module's text).

    **Arguments:** `command`, the command's name, for the one line printed on stderr.

    **Returns:** a context manager; outside the main thread it does nothing. SIGINT stays
    ignored when the process was started with it ignored (a shell's background job, `nohup`).
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    read, write = os.pipe()
    os.set_blocking(write, False)
    previous_fd = signal.set_wakeup_fd(write, warn_on_full_buffer=False)
    previous = {}
    for sig in SIGNALS:
        if sig == signal.SIGINT and signal.getsignal(sig) == signal.SIG_IGN:
            continue
        # The Python half does nothing: the watcher acts, whether or not the main thread ever
        # gets back to bytecode.
        previous[sig] = signal.signal(sig, lambda signum, frame: None)

    def watch():
        while True:
            try:
                data = os.read(read, 1)
            except OSError:
                return
            if not data or data[0] == 0:  # closed, or our own wake-up at the end
                return
            if data[0] in previous:
                _end(command, data[0])

    watcher = threading.Thread(target=watch, name="piest-signal-watcher", daemon=True)
    watcher.start()
    _GUARDING.append(command)
    try:
        yield
    finally:
        _GUARDING.pop()
        for sig, handler in previous.items():
            signal.signal(sig, handler if handler is not None else signal.SIG_DFL)
        signal.set_wakeup_fd(previous_fd)
        with contextlib.suppress(OSError):
            os.write(write, b"\0")
        watcher.join(timeout=1.0)
        for fd in (read, write):
            with contextlib.suppress(OSError):
                os.close(fd)


def entry() -> None:
    """The `piest` console script: run the command line, ending at once on a signal."""
    from . import main

    compile_cache.enable()
    argv = sys.argv[1:]
    command = next((a for a in argv if not a.startswith("-")), "")
    with guard(command):
        code = main(argv)
    sys.exit(code)
