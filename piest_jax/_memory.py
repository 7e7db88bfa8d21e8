"""Heap memory that the process freed, given back to the operating system between large steps.

A fit on a long record allocates and frees many large buffers from several threads. glibc's
allocator keeps freed memory inside its per-thread arenas, where fragmentation stops it from
shrinking them: on a 2^18-sample model selection the process held 1.48 GB resident of which
1.1 GB was already free (measured before this existed, `experiments/README.md`). `malloc_trim`
hands those free pages back. Elsewhere (macOS, Windows, musl) there is no such call and nothing
is done.
"""

import ctypes
import functools
import sys


@functools.cache
def _malloc_trim():
    if not sys.platform.startswith("linux"):
        return None
    try:
        # The process's own C library: the allocator that NumPy and XLA's CPU buffers use.
        trim = ctypes.CDLL(None).malloc_trim
    except (OSError, AttributeError):  # no glibc
        return None
    trim.argtypes = [ctypes.c_size_t]
    trim.restype = ctypes.c_int
    return trim


def release_freed_memory() -> bool:
    """Give the heap's free pages back to the operating system, where the C library allows it.

    **Returns:** whether any memory was released (False where the call does not exist).
    """
    trim = _malloc_trim()
    return bool(trim(0)) if trim is not None else False
