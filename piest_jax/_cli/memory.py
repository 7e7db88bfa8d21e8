"""Memory a command's options and inputs need, estimated before any work, against what the
process can have (the machine's available memory, its address-space limit, its cgroup's limit):
a request that cannot fit is refused in one line (exit 2) at once, rather than failing after
minutes with `MemoryError` or being killed by the system.

The estimates count the largest arrays a command holds at one time (8-byte floats), times a
small factor for the copies and workspaces JAX and the solvers make; they are meant to be right
within a factor of two or three, which is what matters against sizes off by orders of magnitude.
"""

import os

from ._common import CLIError

FLOAT = 8


def _system_bytes() -> int | None:
    """The memory the system can give a process now (Linux: MemAvailable), or None."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def _status_bytes(key: str) -> int | None:
    """A size from /proc/self/status (`VmSize`: the address space this process uses)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith(key + ":"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def _address_space_room() -> int | None:
    """What this process's address-space limit (RLIMIT_AS, `ulimit -v`) leaves it, or None."""
    try:
        import resource

        soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    except (ImportError, OSError, ValueError):
        return None
    if soft == resource.RLIM_INFINITY or soft < 0:
        return None
    used = _status_bytes("VmSize") or 0
    return max(int(soft) - used, 0)


def _read_number(path: str) -> int | None:
    try:
        with open(path) as f:
            text = f.read().strip()
    except OSError:
        return None
    return int(text) if text.isdigit() else None  # "max": no limit


def _cgroup_room(root: str = "/sys/fs/cgroup") -> int | None:
    """What this process's cgroup memory limit leaves (v2 memory.max, v1 limit_in_bytes)."""
    for limit, usage in (
        ("memory.max", "memory.current"),
        ("memory/memory.limit_in_bytes", "memory/memory.usage_in_bytes"),
    ):
        top = _read_number(os.path.join(root, limit))
        # cgroup v1 states "no limit" as a number near 2^63.
        if top is not None and top < 2**60:
            return max(top - (_read_number(os.path.join(root, usage)) or 0), 0)
    return None


# Each source of the available memory, with how a refusal names it.
_SOURCES = (
    (_system_bytes, "available"),
    (_address_space_room, "left under this process's address-space limit (ulimit -v)"),
    (_cgroup_room, "left under its cgroup's memory limit"),
)


def _available() -> tuple[int | None, str]:
    """The least memory any source allows, and how to name it."""
    found = [(n, what) for source, what in _SOURCES if (n := source()) is not None]
    return min(found) if found else (None, "available")


def available_bytes() -> int | None:
    """The memory this process can have now: the least of what the system has available, what
    its address-space limit leaves and what its cgroup's limit leaves; None when none is known."""
    return _available()[0]


def _size(n: float) -> str:
    for unit, scale in (("TB", 2**40), ("GB", 2**30), ("MB", 2**20)):
        if n >= scale:
            return f"{n / scale:.3g} {unit}"
    return f"{n / 2**10:.3g} kB"


def require(nbytes: float, what: str, advice: str) -> None:
    """Refuse (CLIError) when `nbytes` is more than the memory available.

    **Arguments:** `nbytes`, the estimate; `what`, the options or file that ask for it, as the
    user wrote them; `advice`, what to change.
    """
    avail = available_bytes()
    if avail is not None and nbytes > avail:
        known, label = _available()
        raise CLIError(
            f"{what} needs about {_size(nbytes)} of memory, more than the {_size(avail)} "
            f"{label if known == avail else 'available'}; {advice}"
        )


def fit_bytes(n_samples: int, n_starts: int, n_params: int, *, chunked_past: int | None = None) -> float:
    """A least-squares fit: the Jacobian (samples x parameters) and the residuals per start, all
    starts solved at once, about three copies.

    With `chunked_past`, a record longer than that many samples is fitted by normal equations
    accumulated chunk by chunk (Levenberg-Marquardt on a long record): then about a dozen copies
    of the record, plus the in-memory fit on its first `chunked_past` samples where the starts
    are compared (measured: 1.25 GB for a 10^7-sample fit).
    """
    if chunked_past is not None and n_samples > chunked_past:
        return 12.0 * FLOAT * n_samples + fit_bytes(chunked_past, n_starts, n_params)
    return 3.0 * FLOAT * n_starts * (n_samples * (n_params + 4) + n_params**2)


def map_bytes(n_samples: int, n_plays: int, n_families: int) -> float:
    """The Monte Carlo map: per draw the play outputs (samples x plays) and the Gram matrices
    (plays x plays), one draw of each family at a time, about four copies."""
    return 4.0 * FLOAT * n_families * (n_samples * n_plays + n_plays**2)


def bank_bytes(n_samples: int, n_plays: int) -> float:
    """A play bank's outputs kept over a signal (simulate): samples x plays, about three copies."""
    return 3.0 * FLOAT * n_samples * n_plays


def stream_bytes(n_samples: int, n_plays: int) -> float:
    """A PI model and its inverse run sample by sample (compensate): the plays' states are
    carried, never stored per sample, so signals and parameters in a few dozen copies (measured:
    the same 330 MB, mostly JAX itself, from 2,000 to 20,000 plays and 6,000 to 60,000 samples)."""
    return FLOAT * 32.0 * (n_samples + n_plays)


def diagnose_bytes(n_samples: int) -> float:
    """The diagnosis: its regressors (16 plays and the effects' columns, about 64) over the
    samples, with the solvers' Jacobians, about six copies."""
    return 6.0 * FLOAT * 64 * n_samples


def rls_bytes(n_weights: int, n_samples: int) -> float:
    """An online estimator: its gain matrix (weights x weights) and workspaces, and the weights'
    trajectory."""
    return FLOAT * (6.0 * n_weights**2 + 4.0 * n_weights * min(n_samples, 2000) + 8.0 * n_samples)
