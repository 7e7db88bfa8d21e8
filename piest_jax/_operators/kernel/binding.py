"""The compiled CPU play-bank kernel, as JAX operations with custom gradients.

`play_kernel.cc` holds XLA FFI handlers for the play bank H (T, n) and the fused PI output
y (T,), float32 and float64, forward and backward. They are registered with `jax.ffi` the first time
they are needed. The forward outputs equal the pure-JAX scan: H to the last bit (the same max/min
operations), y up to the order in which the n weighted plays are summed.

Derivatives go through `jax.custom_jvp`. The differentiated forward pass also records, per step and
play, one bit: whether a bound moved the state (which bound follows from the direction of the
input). A third kernel runs the tangent along (du, dr, dx0) forwards in time over those bits (a
moved state takes the input's tangent, a held one keeps its own), and the tangent's transpose,
which reverse mode uses, is the backward kernel: it runs the adjoint recurrence backwards in time
over the same bits (`tangent.py` makes the pair one linear JAX primitive). So `jvp`, `jacfwd`,
`linearize`, `grad` and `jacrev` all work, to first order (a second derivative of a
piecewise-linear operator is zero wherever it exists; for nested differentiation use the scan).
At a kink (the old state exactly equal to a bound) the kernel counts the step as a hold, so the
derivative is the one-sided derivative in which the play does not move; the pure-JAX scan instead
averages the two sides. Likewise for a zero threshold, where both bounds equal u: the kernel gives
the threshold derivative from the admissible side r > 0, the scan the average of both sides (zero).
Both agree everywhere else, in both modes.

Batching (`jax.vmap`) hands the whole batch to one kernel call (`vmap_method="broadcast_all"`), which
splits the signals across the CPU cores (`PIEST_KERNEL_THREADS` caps the thread count).

When the extension was not compiled (no C++ compiler at install time, or PIEST_KERNEL_BUILD=0), does
not load, was compiled against another jaxlib than the one installed (pip builds in an isolated
environment with the newest jaxlib unless told `--no-build-isolation`; an XLA runtime given handlers
built for other headers can break the whole CPU backend), or was compiled for instructions this CPU
lacks, `method="kernel"` and `method="auto"` on
a CPU backend fall back to the scan and warn once per process.

One build holds two kernel modules from the same source: a portable one for the target's baseline
(SSE2 on x86-64: 16-byte vectors) and, where the compiler has the flags, one with AVX2/FMA (32-byte
vectors). The AVX2 module is loaded where CPUID reports both extensions, the portable one elsewhere
or with `PIEST_KERNEL_ISA=portable`; `isa()` says which runs. The play outputs of both equal the
scan's to the last bit; the fused PI output may differ between them in the last bits (its lane sums
follow the vector width).
"""

import functools
import importlib
import importlib.util
import os
import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
from jax import lax
from jaxtyping import Array

from ... import _checks
from . import tangent


def _missing_isa(required, probe=None) -> list[str]:
    """The instruction-set extensions in `required` that this CPU lacks.

    `probe` is a loaded kernel module, whose `cpu_has` asks CPUID (x86); without one, Linux's
    /proc/cpuinfo tells, and elsewhere nothing is reported missing.
    """
    if probe is not None and hasattr(probe, "cpu_has"):
        return [name for name in required if not probe.cpu_has(name)]
    try:
        with open("/proc/cpuinfo") as f:
            flags = next((ln.split(":", 1)[1].split() for ln in f if ln.startswith("flags")), None)
    except OSError:
        return []
    return [] if flags is None else [name for name in required if name not in flags]


def _installed_jaxlib() -> str:
    from importlib.metadata import version

    return version("jaxlib")


def _built_with(ext) -> str:
    """The jaxlib version `ext` was compiled against ("unknown" for a build that does not say)."""
    return ext.built_with() if hasattr(ext, "built_with") else "unknown"


def _import(module: str):
    """(the kernel module `module`, "") or (None, why it cannot be used)."""
    name = f"{__package__}.{module}"
    if importlib.util.find_spec(name) is None:
        return None, "it was not built when the package was installed"
    try:
        ext = importlib.import_module(name)
    except ImportError as err:  # built, but unloadable here (another Python or jaxlib, say)
        return None, f"it does not load: {err}"
    built, installed = _built_with(ext), _installed_jaxlib()
    if built != installed:
        return None, (
            f"it was compiled against jaxlib {built}, but jaxlib {installed} is installed; "
            "reinstall piest_jax against the installed jaxlib (pip install --no-build-isolation ...)"
        )
    return ext, ""


# The kernel builds: the portable module (the target's baseline, SSE2 on x86-64) and, where the
# compiler could, one with AVX2/FMA, taken on CPUs that have them. PIEST_KERNEL_ISA=portable keeps
# the portable module (to compare the two, or to rule the wide one out).
_ISA_CHOICES = ("auto", "portable")
_FAST = ("_play_kernel_avx2", ("avx2", "fma"))


def _load():
    choice = os.environ.get("PIEST_KERNEL_ISA", "auto")
    if choice not in _ISA_CHOICES:
        return None, f"PIEST_KERNEL_ISA={choice!r} is not one of {', '.join(_ISA_CHOICES)}"
    portable, reason = _import("_play_kernel")
    if portable is None:
        return None, reason
    module, isa = _FAST
    if choice == "auto" and not _missing_isa(isa, portable):
        fast, _ = _import(module)
        if fast is not None:
            return fast, ""
    missing = _missing_isa(portable.isa(), portable)
    if missing:  # built with machine flags (CFLAGS=-march=...) elsewhere: running it would crash
        return None, (
            f"it was compiled for {', '.join(missing)}, which this CPU lacks; reinstall on this "
            "machine, or without -march/-m flags in CFLAGS"
        )
    return portable, ""


def isa() -> tuple[str, ...] | None:
    """The instruction-set extensions of the kernel in use (() for the portable build), or None.

    **Returns:** `("avx2", "fma")` when the AVX2 build runs, `()` for the portable build (the
    target's baseline: SSE2 on x86-64), None when no kernel is available.
    """
    return None if _ext is None else tuple(_ext.isa())


_ext, _IMPORT_ERROR = _load()

_DTYPES = {jnp.dtype(jnp.float32): "f32", jnp.dtype(jnp.float64): "f64"}


@functools.cache
def _register(ext) -> None:
    for name, capsule in ext.registrations().items():
        jax.ffi.register_ffi_target(name, capsule, platform="cpu")


def available() -> bool:
    """True when the compiled kernel is importable; registers its FFI targets on first call.

    **Returns:** whether `method="kernel"` runs the compiled kernel on this installation.
    """
    if _ext is None:
        return False
    _register(_ext)
    return True


@functools.cache
def _warn_fallback() -> None:
    # functools.cache makes this fire once per process.
    warnings.warn(
        f"piest_jax: the compiled play kernel is not available ({_IMPORT_ERROR}); the play bank "
        "falls back to the pure-JAX scan. Reinstall with a C++ compiler present (and "
        "PIEST_KERNEL_BUILD unset) to build it.",
        RuntimeWarning,
        stacklevel=4,
    )


def use_kernel(method: str) -> bool:
    """Whether a play-bank `method` runs the compiled kernel here.

    `"kernel"` asks for it; `"auto"` takes it on a CPU backend (on others, `play.resolved` takes
    the associative scan). On a CPU backend without the compiled extension both fall back to the
    scan, warning once per process.

    **Arguments:** `method`, the play method name.

    **Returns:** True to call the kernel, False to use the scan.
    """
    if method not in ("kernel", "auto"):
        return False
    if jax.default_backend() != "cpu":
        if method == "auto":
            return False
        raise ValueError(
            f"method='kernel' runs on CPU only, but the default backend is "
            f"{jax.default_backend()!r}; use method='scan' or 'auto'"
        )
    if not available():
        _warn_fallback()
        return False
    return True


def _suffix(x: Array) -> str:
    try:
        return _DTYPES[jnp.dtype(x.dtype)]
    except KeyError:
        raise ValueError(
            f"the play kernel supports float32 and float64, got {x.dtype}; cast the input or use method='scan'"
        ) from None


def _code_bytes(n: int, dtype) -> int:
    # Bytes of branch codes per step (one bit per play, padded), as the kernel lays them out.
    return _ext.code_bytes(n, jnp.dtype(dtype).itemsize)


def _call(kind: str, x: Array, shapes, *args):
    if not available():
        raise RuntimeError(
            f"piest_jax: the compiled play kernel is not available ({_IMPORT_ERROR}); use method='scan' or 'auto'"
        )
    return jax.ffi.ffi_call(f"piest_{kind}_{_suffix(x)}", shapes, vmap_method="broadcast_all")(*args)


def _sds(shape, dtype):
    return jax.ShapeDtypeStruct(shape, dtype)


def _validate(u: Array, r: Array, **per_play: Array) -> None:
    # The FFI handlers trust their buffers, so every shape and dtype is checked here, at trace time.
    if u.ndim != 1 or u.shape[0] < 1:
        raise ValueError(f"the play kernel needs one signal u of shape (T,), T >= 1, got {u.shape}")
    if r.ndim != 1 or r.shape[0] < 1:
        raise ValueError(f"the play kernel needs thresholds r of shape (n,), n >= 1, got {r.shape}")
    _suffix(u)
    for name, a in (("r", r), *per_play.items()):
        if a.shape != r.shape:
            raise ValueError(f"the play kernel needs `{name}` of shape {r.shape}, got {a.shape}")
        if a.dtype != u.dtype:
            raise ValueError(
                f"the play kernel needs one dtype for all arguments: u is {u.dtype}, `{name}` is {a.dtype}"
            )


def _check_finite(u: Array, r: Array) -> Array:
    """`r`, made to depend on a check that `u` holds no NaN or inf.

    `_checks.finite` attaches its `eqx.error_if` to the checked array itself, which for a long
    signal makes XLA copy the whole signal (under `vmap` and `grad`, into freshly faulted memory).
    Here the error is attached to a zero scalar that is added to the thresholds, so the check
    costs one fused reduction over `u` (u * 0 is NaN exactly where u is NaN or inf) and adds
    nothing (r + 0 == r).
    """
    if _checks.is_concrete(u):
        _checks.finite(u, "u")
        return r
    bad = ~jnp.isfinite(jnp.sum(lax.stop_gradient(u) * 0))
    return r + eqx.error_if(jnp.zeros((), r.dtype), bad, "`u` contains NaN or inf")


def bank(u: Array, r: Array, x0: Array, *, check_finite: bool = True) -> Array:
    """The play outputs H (T, n) for input `u` (T,), thresholds `r` (n,) and states `x0` (n,).

    All three must share one float dtype (float32 or float64); anything else raises `ValueError`,
    and so does NaN or inf in `u` (through `eqx.error_if` under `jit`). Composes with `jit`,
    `vmap` (one kernel call for the whole batch), forward mode (`jvp`, `jacfwd`) and
    reverse mode (`grad`) with respect to all three arguments.

    **Arguments:**

    - `u`: the input (T,).
    - `r`: the thresholds (n,), non-negative.
    - `x0`: the initial states (n,).
    - `check_finite`: False for an input finite by construction (see `play._bank`).

    **Returns:** H (T, n), equal to the pure-JAX scan to the last bit.
    """
    u, r, x0 = (jnp.asarray(a) for a in (u, r, x0))
    _validate(u, r, x0=x0)
    return _bank(u, _check_finite(u, r) if check_finite else r, x0)


def _bank_bwd(u, r, x0, codes, gh):
    shapes = (_sds(u.shape, u.dtype), _sds(r.shape, u.dtype), _sds(x0.shape, u.dtype))
    return tuple(_call("bank_bwd", u, shapes, u, r, x0, codes, gh.astype(u.dtype)))


def _bank_tangent_rule(u, r, x0, codes, du, dr, dx0):
    return _call("bank_tangent", u, _sds((u.shape[0], r.shape[0]), u.dtype), u, r, x0, codes, du, dr, dx0)


_bank_tangent = tangent.linear_primitive("piest_bank_tangent", 4, _bank_tangent_rule, lambda u, r, *_: u + r, _bank_bwd)


@jax.custom_jvp
def _bank(u, r, x0):
    return _call("bank_fwd", u, _sds((u.shape[0], r.shape[0]), u.dtype), u, r, x0)


@_bank.defjvp
def _bank_jvp(primals, tangents):
    u, r, x0 = primals
    t, n = u.shape[0], r.shape[0]
    shapes = (_sds((t, n), u.dtype), _sds((t, _code_bytes(n, u.dtype)), jnp.uint8))
    h, codes = _call("bank_fwd_res", u, shapes, u, r, x0)
    return h, _bank_tangent.bind(u, r, x0, codes, *tangents)


def pi_output(u: Array, r: Array, x0: Array, w: Array) -> Array:
    """The fused PI output y_t = Σ_j w_j H_{r_j}[u](t), without materialising H.

    All four must share one float dtype (float32 or float64); anything else raises `ValueError`,
    and so does NaN or inf in `u` (through `eqx.error_if` under `jit`). Composes with `jit`,
    `vmap` (one kernel call for the whole batch), forward mode (`jvp`, `jacfwd`) and
    reverse mode (`grad`) with respect to all four arguments.

    **Arguments:**

    - `u`: the input (T,).
    - `r`: the thresholds (n,), non-negative.
    - `x0`: the initial states (n,).
    - `w`: the weights (n,).

    **Returns:** y (T,). The n terms are summed in a fixed order (lane-wise partial sums over
    blocks of plays, then a halving tree), so y can differ from `H @ w` in the last bits.
    """
    u, r, x0, w = (jnp.asarray(a) for a in (u, r, x0, w))
    _validate(u, r, x0=x0, w=w)
    return _pi(u, _check_finite(u, r), x0, w)


def _pi_tangent_rule(u, r, x0, w, codes, du, dr, dx0, dw):
    return _call("pi_tangent", u, _sds(u.shape, u.dtype), u, r, x0, w, codes, du, dr, dx0, dw)


def _pi_bwd(u, r, x0, w, codes, gy):
    shapes = (_sds(u.shape, u.dtype),) + tuple(_sds(a.shape, u.dtype) for a in (r, x0, w))
    return tuple(_call("pi_bwd", u, shapes, u, r, x0, w, codes, gy.astype(u.dtype)))


_pi_tangent = tangent.linear_primitive("piest_pi_tangent", 5, _pi_tangent_rule, lambda u, *_: u, _pi_bwd)


@jax.custom_jvp
def _pi(u, r, x0, w):
    return _call("pi_fwd", u, _sds(u.shape, u.dtype), u, r, x0, w)


@_pi.defjvp
def _pi_jvp(primals, tangents):
    u, r, x0, w = primals
    codes = _sds((u.shape[0], _code_bytes(r.shape[0], u.dtype)), jnp.uint8)
    y, codes = _call("pi_fwd_res", u, (_sds(u.shape, u.dtype), codes), u, r, x0, w)
    return y, _pi_tangent.bind(u, r, x0, w, codes, *tangents)
