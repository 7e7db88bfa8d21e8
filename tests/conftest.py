"""Test configuration: float64 everywhere unless a test asks for float32, deterministic hypothesis."""

import os
import shutil
import tempfile

import jax
import pytest
from hypothesis import HealthCheck, settings

# Tests compare against float64 NumPy references; the library itself never touches jax.config.
jax.config.update("jax_enable_x64", True)

settings.register_profile(
    "ci",
    max_examples=60,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.too_slow],
)
settings.load_profile("ci")


def pytest_configure(config):
    """The `piest` processes the tests start share one compilation cache of their own, removed at
    the end, rather than the user's (the test workers inherit the variable)."""
    if not hasattr(config, "workerinput") and "PIEST_COMPILE_CACHE" not in os.environ:
        folder = tempfile.mkdtemp(prefix="piest-test-compiled-")
        os.environ["PIEST_COMPILE_CACHE"] = folder
        config._piest_compile_cache = folder


def pytest_unconfigure(config):
    folder = getattr(config, "_piest_compile_cache", None)
    if folder is not None:
        shutil.rmtree(folder, ignore_errors=True)
        os.environ.pop("PIEST_COMPILE_CACHE", None)


@pytest.fixture
def rng():
    import numpy as np

    return np.random.default_rng(12345)


def _memory_maps() -> tuple[int, int] | None:
    """(this process's memory mappings, the kernel's limit on them), where Linux tells."""
    try:
        with open("/proc/self/maps") as f:
            count = sum(1 for _ in f)
        with open("/proc/sys/vm/max_map_count") as f:
            return count, int(f.read())
    except (OSError, ValueError):
        return None


@pytest.fixture(autouse=True, scope="module")
def _bounded_compiled_programs():
    """Free the compiled programs of a test file once they take a third of the mapping limit.

    Each compiled XLA CPU program holds about three memory mappings for its code and data, and JAX
    keeps every program it compiled for the life of the process. A test worker compiles thousands
    (every test builds its own shapes and settings), and at the kernel's limit on mappings (65530
    by default) the next compilation fails to map its code and the worker dies in the compiler.
    """
    yield
    maps = _memory_maps()
    if maps is not None and maps[0] > maps[1] // 3:
        jax.clear_caches()
