"""Freed heap memory goes back to the operating system (glibc's malloc_trim, where it exists)."""

import ctypes

import pytest

from piest_jax import _memory as memory
from piest_jax._memory import _malloc_trim, release_freed_memory


def _resident_mb() -> float:
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) / 1024 for line in f if line.startswith("VmRSS"))


def test_without_malloc_trim_nothing_is_done(monkeypatch):
    # macOS, Windows, musl: no such call; the release says it did nothing instead of failing.
    monkeypatch.setattr(memory, "_malloc_trim", lambda: None)
    assert memory.release_freed_memory() is False


@pytest.mark.skipif(_malloc_trim() is None, reason="no malloc_trim in this C library")
def test_freed_fragmented_heap_is_given_back():
    # Many 4 kB blocks (below the allocator's mmap threshold, so they live on the heap), every
    # one freed but the last: the block at the top pins the heap, so the allocator keeps the
    # freed pages resident until they are trimmed.
    libc = ctypes.CDLL(None)
    libc.malloc.restype = ctypes.c_void_p
    libc.malloc.argtypes = [ctypes.c_size_t]
    libc.free.argtypes = [ctypes.c_void_p]
    blocks = [libc.malloc(4096) for _ in range(60_000)]  # about 240 MB
    for b in blocks:
        ctypes.memset(b, 1, 4096)  # touch the pages so they are resident
    for b in blocks[:-1]:
        libc.free(b)
    before = _resident_mb()
    assert release_freed_memory()
    after = _resident_mb()
    libc.free(blocks[-1])
    assert before - after > 150, (before, after)
