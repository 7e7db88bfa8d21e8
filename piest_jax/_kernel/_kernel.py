"""The compiled CPU play-bank kernel, as JAX operations with custom gradients.

`play_kernel.cc` holds XLA FFI handlers for the play bank H (T, n) and the fused PI output
y (T,), float32 and float64, forward and backward. They are registered with `jax.ffi` the first time
they are needed. The forward outputs equal the pure-JAX scan: H to the last bit (the same max/min
operations), y up to the order in which the n weighted plays are summed.

Gradients go through `jax.custom_vjp`. The differentiated forward pass also records, per step and
play, which branch of the clamp was active (lower bound u - r, upper bound u + r, or hold), and the
backward kernel runs the adjoint recurrence backwards in time over those codes. At a kink (the old
state exactly equal to a bound) the kernel counts the step as a hold, so the derivative is the
one-sided derivative in which the play does not move; the pure-JAX scan instead averages the two
sides. Both agree everywhere else.

Batching (`jax.vmap`) hands the whole batch to one kernel call (`vmap_method="broadcast_all"`), which
splits the signals across the CPU cores (`PIEST_KERNEL_THREADS` caps the thread count).

When the extension was not compiled (no C++ compiler at install time), `method="kernel"` falls back
to the scan and warns once per process; `method="auto"` falls back silently.
"""

import functools
import warnings

import jax
import jax.numpy as jnp
from jaxtyping import Array

try:
    from . import _play_kernel as _ext
except ImportError as _err:  # the optional extension was not built
    _ext = None
    _IMPORT_ERROR: str = str(_err)
else:
    _IMPORT_ERROR = ""

_DTYPES = {jnp.dtype(jnp.float32): "f32", jnp.dtype(jnp.float64): "f64"}


@functools.cache
def available() -> bool:
    """True when the compiled kernel is importable; registers its FFI targets on first call.

    **Returns:** whether `method="kernel"` runs the compiled kernel on this installation.
    """
    if _ext is None:
        return False
    for name, capsule in _ext.registrations().items():
        jax.ffi.register_ffi_target(name, capsule, platform="cpu")
    return True


@functools.cache
def _warn_fallback() -> None:
    # functools.cache makes this fire once per process.
    warnings.warn(
        "piest_jax: the compiled play kernel is not available "
        f"({_IMPORT_ERROR or 'not built'}); method='kernel' falls back to the pure-JAX scan. "
        "Reinstall with a C++ compiler present to build it.",
        RuntimeWarning,
        stacklevel=3,
    )


def use_kernel(method: str) -> bool:
    """Whether a play-bank `method` runs the compiled kernel here.

    `"kernel"` asks for it (warning once if it is missing); `"auto"` takes it on a CPU backend when
    it is built and the scan otherwise.

    **Arguments:** `method`, the play method name.

    **Returns:** True to call the kernel, False to use the scan.
    """
    if method == "auto":
        return jax.default_backend() == "cpu" and available()
    if method != "kernel":
        return False
    if jax.default_backend() != "cpu":
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
            f"the play kernel supports float32 and float64, got {x.dtype}; "
            "cast the input or use method='scan'"
        ) from None


def _padded(n: int) -> int:
    lanes = _ext.lanes()
    return -(-n // lanes) * lanes


def _call(kind: str, x: Array, shapes, *args):
    return jax.ffi.ffi_call(
        f"piest_{kind}_{_suffix(x)}", shapes, vmap_method="broadcast_all"
    )(*args)


def _sds(shape, dtype):
    return jax.ShapeDtypeStruct(shape, dtype)


@jax.custom_vjp
def bank(u: Array, r: Array, x0: Array) -> Array:
    """The play outputs H (T, n) for input `u` (T,), thresholds `r` (n,) and states `x0` (n,).

    All three must share one float dtype. Composes with `jit`, `vmap` and reverse-mode `grad`.

    **Arguments:**

    - `u`: the input (T,).
    - `r`: the thresholds (n,).
    - `x0`: the initial states (n,).

    **Returns:** H (T, n), equal to the pure-JAX scan to the last bit.
    """
    return _call("bank_fwd", u, _sds((u.shape[0], r.shape[0]), u.dtype), u, r, x0)


def _bank_fwd(u, r, x0):
    t, n = u.shape[0], r.shape[0]
    shapes = (_sds((t, n), u.dtype), _sds((t, _padded(n)), jnp.int8))
    h, codes = _call("bank_fwd_res", u, shapes, u, r, x0)
    return h, (u, r, x0, codes)


def _bank_bwd(res, gh):
    u, r, x0, codes = res
    shapes = (_sds(u.shape, u.dtype), _sds(r.shape, u.dtype), _sds(x0.shape, u.dtype))
    return tuple(_call("bank_bwd", u, shapes, u, r, x0, codes, gh.astype(u.dtype)))


bank.defvjp(_bank_fwd, _bank_bwd)


@jax.custom_vjp
def pi_output(u: Array, r: Array, x0: Array, w: Array) -> Array:
    """The fused PI output y_t = Σ_j w_j H_{r_j}[u](t), without materialising H.

    All four must share one float dtype. Composes with `jit`, `vmap` and reverse-mode `grad`.

    **Arguments:**

    - `u`: the input (T,).
    - `r`: the thresholds (n,).
    - `x0`: the initial states (n,).
    - `w`: the weights (n,).

    **Returns:** y (T,). The n terms are summed in a fixed order (16 partial sums over blocks of
    plays, then a halving tree), so y can differ from `H @ w` in the last bits.
    """
    return _call("pi_fwd", u, _sds(u.shape, u.dtype), u, r, x0, w)


def _pi_fwd(u, r, x0, w):
    shapes = (_sds(u.shape, u.dtype), _sds((u.shape[0], _padded(r.shape[0])), jnp.int8))
    y, codes = _call("pi_fwd_res", u, shapes, u, r, x0, w)
    return y, (u, r, x0, w, codes)


def _pi_bwd(res, gy):
    u, r, x0, w, codes = res
    shapes = (_sds(u.shape, u.dtype),) + tuple(_sds(a.shape, u.dtype) for a in (r, x0, w))
    return tuple(_call("pi_bwd", u, shapes, u, r, x0, w, codes, gy.astype(u.dtype)))


pi_output.defvjp(_pi_fwd, _pi_bwd)
