"""The play (backlash) and stop operators, paper eqs. (1)-(2).

One play step is a clamp: x_t = max(u_t - r, min(u_t + r, x_{t-1})). The sequential form is a step
function plus a thin `lax.scan`. Because clamps compose into clamps,

    clamp[l2, h2] ∘ clamp[l1, h1] = clamp[clamp[l2, h2](l1), clamp[l2, h2](h1)],

the same outputs also follow from `lax.associative_scan` in O(log T) depth. max and min only ever
select one of their arguments, so both forms round identically: the outputs agree to the last bit.

At a switching instant (a held state exactly on a bound u ± r) the output is not differentiable.
JAX's max/min then share the gradient equally between the tied arguments, so with the scan a
derivative taken exactly at a single kink is the average of the two one-sided derivatives; anywhere
else it is exact. The associative form regroups the clamps, so at a kink it may return another
one-sided combination; away from kinks both agree. A zero threshold lies on the boundary of r >= 0,
so a derivative with respect to it is not a meaningful sensitivity.

The thresholds may vary over time, r of shape (T, n) with one row per sample: the step at sample t
then clamps to [u_t - r_t, u_t + r_t] (rate-dependent hysteresis, where the loops widen with the
input's rate). The clamps still compose into clamps, so the associative form holds as well; the
compiled kernel takes constant thresholds only, and on a CPU backend time-varying ones run on the
scan.
"""

from typing import Literal, TypeAlias

import jax
import jax.numpy as jnp
from jax import lax
from jaxtyping import Array, ArrayLike, Float

from .. import _checks
from .._custom_types import ScalarLike, SignalLike, ThresholdsLike

Method = Literal["scan", "associative", "kernel", "auto"]
# "kernel" is the compiled CPU kernel (`kernel/`); "auto" takes it on CPU when built, the associative
# scan on accelerators, else the scan (`resolved`).
METHODS = ("scan", "associative", "kernel", "auto")

TimeVaryingThresholdsLike: TypeAlias = Float[ArrayLike, "time plays"]


def play_step(x: Array, u: Array, r: Array) -> Array:
    """One sample of the play operator: the state `x` clamped to [u - r, u + r].

    **Arguments:**

    - `x`: the previous state, scalar or (n,).
    - `u`: the input at this sample.
    - `r`: the threshold(s), broadcastable against `x`.

    **Returns:** the new state, which is also the play's output at this sample.
    """
    return jnp.maximum(u - r, jnp.minimum(u + r, x))


# Jitted at module level so that eager calls with the same shapes reuse one compiled program: an
# eager `lax.scan` over a fresh closure compiles (and keeps) a new executable on every call.
@jax.jit
def _scan(u: Array, r: Array, x0: Array) -> Array:
    if r.ndim == 2:

        def step_varying(x, ur):
            x = play_step(x, ur[0], ur[1])
            return x, x

        _, xs = lax.scan(step_varying, x0, (u, r))
        return xs

    def step(x, ut):
        x = play_step(x, ut, r)
        return x, x

    _, xs = lax.scan(step, x0, u)
    return xs


def _compose(earlier, later):
    lo1, hi1 = earlier
    lo2, hi2 = later
    # The later clamp applied to the earlier clamp's bounds gives the composed clamp's bounds.
    return (
        jnp.maximum(lo2, jnp.minimum(hi2, lo1)),
        jnp.maximum(lo2, jnp.minimum(hi2, hi1)),
    )


@jax.jit
def _associative(u: Array, r: Array, x0: Array) -> Array:
    lo = u[:, None] - r
    hi = u[:, None] + r
    lo_c, hi_c = lax.associative_scan(_compose, (lo, hi))
    return jnp.maximum(lo_c, jnp.minimum(hi_c, x0))


def resolved(method: str, *, time_varying: bool = False, dtype=None) -> str:
    """The play method that runs here for `method`: `"scan"`, `"associative"` or `"kernel"`.

    `"auto"` is the compiled kernel on a CPU backend where it is built, the associative scan on
    an accelerator (where one step of the sequential scan is a pass of a device loop: on an H100
    the associative form ran 330 to 3,600 times faster on one signal and 7 times on a batch of
    4096, `experiments/bench_gpu.py`), and the scan otherwise. `"kernel"` without the compiled
    extension falls back to the scan (warning once); on an accelerator it is refused. The kernel
    takes constant thresholds only: for time-varying ones `"kernel"` and `"auto"` are the scan on
    a CPU backend, without a warning (there, on one signal, the scan ran several times faster than
    the associative form). `"auto"` on a dtype other than float32 and float64 is the scan too.

    **Arguments:** `method`, one of `METHODS`; `time_varying`, whether the thresholds vary over
    time (shape (T, n)); `dtype`, the dtype the plays run in (None: not known here).

    **Returns:** the method name that runs.
    """
    if method not in METHODS:
        raise ValueError(f"unknown play method {method!r}; choose one of {METHODS}")
    if method == "auto" and on_accelerator():
        return "associative"
    if method in ("kernel", "auto"):
        if time_varying and not on_accelerator():
            return "scan"
        if method == "auto" and dtype is not None and jnp.dtype(dtype) not in (jnp.float32, jnp.float64):
            return "scan"
        from . import kernel as _kernel

        return "kernel" if _kernel.use_kernel(method) else "scan"
    return method


def on_accelerator() -> bool:
    """Whether JAX's default backend is not the CPU (a GPU or TPU)."""
    return jax.default_backend() != "cpu"


def _uses_kernel(method: str, time_varying: bool = False, dtype=None) -> bool:
    """Whether `method` runs the compiled kernel here (it checks its input for NaN/inf itself)."""
    return method in ("kernel", "auto") and resolved(method, time_varying=time_varying, dtype=dtype) == "kernel"


def _bank(u: Array, r: Array, x0: Array, method: str, *, check_finite: bool = True) -> Array:
    """Play outputs (T, n) for thresholds r (n,) or time-varying (T, n) and initial states x0 (n,).

    `check_finite=False` leaves out the kernel's NaN/inf check of a traced `u`, for inputs finite
    by construction: the check is a host callback, and JAX keeps no compiled program with one in
    its persistent compilation cache.
    """
    method = resolved(method, time_varying=r.ndim == 2, dtype=u.dtype)
    if method == "kernel":
        from . import kernel as _kernel

        return _kernel.bank(u, r, x0, check_finite=check_finite)
    if method == "associative":
        return _associative(u, r, x0)
    return _scan(u, r, x0)


def _thresholds(r: Array, n_samples: int) -> Array:
    """Thresholds: a scalar, a vector (n,) or time-varying (T, n), finite and non-negative."""
    if r.ndim < 2:
        return _checks.thresholds(r, "r")
    if r.ndim > 2 or r.shape[0] != n_samples:
        raise ValueError(
            f"`r` must be a scalar or a vector (n,), or ({n_samples}, n) for thresholds that vary "
            f"over time (one row per sample of `u`); got shape {r.shape}"
        )
    if r.shape[1] < 1:
        raise ValueError(f"`r` is empty: its shape {r.shape} holds no play")
    # The value checks are those of a bank, on every sample's thresholds at once.
    return _checks.thresholds(r.reshape(-1), "r").reshape(r.shape)


def _prepare(u, r, x0, x0_name="x0", method="auto") -> tuple[Array, Array, Array, Array]:
    u = _checks.signal(u)
    r = _checks.as_float_array(r, "r")
    r = _thresholds(r, u.shape[0])
    n = None if r.ndim == 0 else r.shape[-1]
    x0 = _checks.per_play(x0, n, x0_name)
    dtype = jnp.result_type(u, r, x0)
    if not _uses_kernel(method, time_varying=r.ndim == 2, dtype=dtype):
        u = _checks.finite(u, "u")
    u, r, x0 = u.astype(dtype), r.astype(dtype), x0.astype(dtype)
    rv = jnp.atleast_1d(r)
    x0v = jnp.broadcast_to(x0, rv.shape[-1:])
    return u, r, rv, x0v


def play(
    u: SignalLike,
    r: ThresholdsLike | TimeVaryingThresholdsLike,
    x0: ScalarLike | ThresholdsLike = 0.0,
    *,
    method: Method = "auto",
) -> Array:
    """The play operator H_r[u] (paper eq. 1) on a sampled input.

    The state before the first sample is `x0`, so the first output is
    max(u_0 - r, min(u_0 + r, x0)) (paper eq. 2); `x0` need not be zero. Thresholds that vary
    over time (T, n) give each sample its own: x_t = max(u_t - r_t, min(u_t + r_t, x_{t-1})).

    **Arguments:**

    - `u`: the input signal, shape (T,).
    - `r`: one threshold (scalar), a bank of thresholds (n,), or thresholds that vary over time
      (T, n), one row per sample of `u`; all >= 0.
    - `x0`: the initial state(s), a scalar or (n,).
    - `method`: `"auto"` (the default: the compiled kernel on a CPU backend when it was built,
      the associative scan on an accelerator, where it runs faster), `"scan"` (sequential
      `lax.scan`, the reference), `"associative"` (`lax.associative_scan`, O(log T) depth, same
      outputs to the last bit) or `"kernel"` (the compiled CPU kernel, same outputs to the last
      bit; falls back to the scan with a warning when it was not built). All differentiate in
      forward and reverse mode; at a tie (a state exactly on a bound, or a zero threshold) the
      kernel takes a one-sided derivative where the scans average both sides. The kernel takes
      float32/float64 and constant thresholds only: otherwise `"auto"` (and, for time-varying
      thresholds, `"kernel"`) runs the scan on a CPU backend (no warning).

    **Returns:** the play output, (T,) for a scalar `r` and (T, n) for a vector or time-varying
    `r`.
    """
    u, r, rv, x0v = _prepare(u, r, x0, method=method)
    out = _bank(u, rv, x0v, method)
    return out[:, 0] if r.ndim == 0 else out


def stop(
    u: SignalLike,
    r: ThresholdsLike | TimeVaryingThresholdsLike,
    e0: ScalarLike | ThresholdsLike = 0.0,
    *,
    method: Method = "auto",
) -> Array:
    """The stop operator E_r[u] = u - H_r[u], the play's dual.

    Its output always lies in [-r, r] and follows e_t = clamp(e_{t-1} + u_t - u_{t-1}, -r, r), with
    `e0` the stop's state before the first sample (a relaxed stop has e0 = 0). This is the play with
    initial state u_0 - e0. With thresholds that vary over time the bound at sample t is r_t.

    **Arguments:**

    - `u`: the input signal, shape (T,).
    - `r`: one threshold (scalar), a bank of thresholds (n,), or thresholds that vary over time
      (T, n); all >= 0.
    - `e0`: the stop's initial state(s), a scalar or (n,).
    - `method`: as for [`play`][].

    **Returns:** the stop output, (T,) or (T, n).
    """
    u, r, rv, e0v = _prepare(u, r, e0, "e0", method)
    # u - H lies in [-r, r] exactly, but its rounding can step past r by an ulp; the clip restores
    # the bound without changing any value that was inside it.
    out = jnp.clip(u[:, None] - _bank(u, rv, u[0] - e0v, method), -rv, rv)
    return out[:, 0] if r.ndim == 0 else out
