"""Test configuration: float64 everywhere unless a test asks for float32, deterministic hypothesis."""

import contextlib
import os
import shutil
import tempfile

# Most of the suite's time is XLA compiling programs that then run once on small inputs (about
# nine tenths of tests/test_fit.py's, measured with JAX's compile-time events), and a third of a
# compilation is XLA's optimisation passes (that file's 359 programs: 59 s with them, 38 s
# without). The suite therefore compiles with them off, which took a fifth off its time on 2
# cores (19.0 -> 15.4 min); it passes the same either way. `PIEST_TEST_OPTIMIZED=1`
# keeps them on, as users' programs are compiled: CI's second job runs the operators, kernel,
# estimators, fits, gradients and Monte Carlo map that way. The variable is set before JAX is
# imported so that the `piest` processes and notebook kernels the tests start inherit it.
OPTIMIZED = os.environ.get("PIEST_TEST_OPTIMIZED", "").strip().lower() in {"1", "yes", "true", "on"}
os.environ["JAX_DISABLE_MOST_OPTIMIZATIONS"] = "0" if OPTIMIZED else "1"
# XLA's CPU fusion emitters (its default code generator for fused loops) spend most of a small
# program's compilation: with the older emitters, tests/test_fit.py's and tests/test_long_fit.py's
# programs compile in 39 s instead of 102 s (the two files run in 95 s instead of 167 s, one
# process), with results equal up to rounding. Off with the optimisation passes, for the same
# reason, and on in the optimised job.
FUSION_FLAG = "--xla_cpu_use_fusion_emitters=false"
if not OPTIMIZED and "xla_cpu_use_fusion_emitters" not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {FUSION_FLAG}".strip()
# One BLAS thread per process: the suite runs one worker per core, and OpenBLAS's threads on the
# small matrices of the host-side code only contend with the other worker. The variable reaches
# the `piest` processes and notebook kernels the tests start; this process is limited below.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import jax  # noqa: E402
import pytest  # noqa: E402
from hypothesis import HealthCheck, settings  # noqa: E402
from threadpoolctl import threadpool_limits  # noqa: E402

# Tests compare against float64 NumPy references; the library itself never touches jax.config.
jax.config.update("jax_enable_x64", True)
# Also when a plugin imported JAX before this file set the variable.
jax.config.update("jax_disable_most_optimizations", not OPTIMIZED)

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
    the end, rather than the user's (the test workers inherit the variable); the test workers
    keep their programs there too (`shared_compile_cache`). BLAS runs on one thread (above)."""
    threadpool_limits(limits=1, user_api="blas")
    if not hasattr(config, "workerinput") and "PIEST_COMPILE_CACHE" not in os.environ:
        folder = tempfile.mkdtemp(prefix="piest-test-compiled-")
        os.environ["PIEST_COMPILE_CACHE"] = folder
        config._piest_compile_cache = folder
    folder = shared_compile_cache()
    if folder is not None:
        # Every program, however quickly it compiled: the suite's are small, and a program one
        # worker compiled is loaded by the other worker and by the `piest` processes, which
        # took about a tenth off the suite's time, measured.
        jax.config.update("jax_compilation_cache_dir", folder)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0)
        jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)


def shared_compile_cache() -> str | None:
    """The folder of compiled programs this test session shares, read from `PIEST_COMPILE_CACHE`
    as `piest` reads it, or None when that turns caching off."""
    from piest_jax._cli.compile_cache import cache_folder

    folder = cache_folder()
    return str(folder) if folder is not None and folder.is_dir() else None


def pytest_unconfigure(config):
    folder = getattr(config, "_piest_compile_cache", None)
    if folder is not None:
        shutil.rmtree(folder, ignore_errors=True)
        os.environ.pop("PIEST_COMPILE_CACHE", None)


def pytest_collection_modifyitems(config, items):
    """The files marked `long` first, then the others by their number of tests, each file whole.

    The workers take one file at a time (`--dist loadfile`) as they finish the last. pytest-xdist
    orders the files by their number of tests alone, which put the files of one long test (the
    README's shell session, a minute of subprocesses) last, and one worker ran them alone for the
    run's last minute; with the long files first, what is left at the end is short.
    """
    files: dict = {}
    for item in items:
        files.setdefault(item.path, []).append(item)
    order = sorted(files.values(), key=lambda f: (f[0].get_closest_marker("long") is None, -len(f)))
    items[:] = [item for f in order for item in f]


@contextlib.contextmanager
def optimized_compilation():
    """Compile with XLA's optimisation passes on inside the block (a module-scoped fixture's
    work, which the `optimized` mark of a test does not reach)."""
    if OPTIMIZED:
        yield
        return
    jax.config.update("jax_disable_most_optimizations", False)
    try:
        yield
    finally:
        jax.config.update("jax_disable_most_optimizations", True)


@pytest.fixture(autouse=True)
def _optimized_when_marked(request):
    """A test marked `optimized` compiles with XLA's optimisation passes on: one that runs its
    programs on many draws spends longer running them unoptimised than compiling them (the
    calibration studies over noise draws: 20 s each without the passes, 7-13 s with them)."""
    if request.node.get_closest_marker("optimized") is None:
        yield
        return
    with optimized_compilation():
        yield


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
