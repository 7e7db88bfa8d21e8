"""Creep: a bank of first-order lags of the input, the creep operator of the modified PI model.

Each lag k follows z_k' = (u - z_k)/τ_k. With the input held over each sampling interval and the
state sampled at its end, the exact zero-order-hold discretisation is

    z_k[t] = a_k z_k[t-1] + (1 - a_k) u[t],      a_k = exp(-dt/τ_k),

with z_k[-1] the lag's state before the first sample (at rest at u_0 by default). The creep output
is C[u](t) = Σ_k c_k z_k[t]. A step in u moves the output by Σ c_k (1 - a_k) at once and by Σ c_k
in the end, the rest arriving with time constants τ_k: slow yield after a change of input when
c_k > 0. (Written as Σ c_k (z_k - u), the same model with the PI's first weight lowered by Σ c_k;
the form Σ c_k z_k keeps the composite model's instantaneous slope w_1 + Σ c_k (1 - a_k) positive
whenever every weight is, which the inverse needs.)

The time constants are stored as log τ, so τ > 0 and 0 < a_k < 1 for any parameter value: the
recurrence is stable by construction, also while an optimiser moves the parameters. The
recurrence is linear, so besides the sequential scan it also follows from `lax.associative_scan`
on the affine maps z -> a z + b.
"""

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jaxtyping import Array, Float

from .. import _checks
from .._custom_types import Signal, SignalLike
from .._operators.play import on_accelerator

Lags = Float[Array, " lags"]
LAG_METHODS = ("scan", "associative", "auto")


def lag_step(z: Array, u: Array, a: Array) -> Array:
    """One sample of the lag bank: z <- a z + (1 - a) u.

    **Arguments:** `z` (K,), the states before this sample; `u`, the input at this sample; `a`
    (K,), the per-sample decay factors exp(-dt/τ_k).

    **Returns:** the new states (K,), which are also the lags' outputs at this sample.
    """
    return a * z + (1.0 - a) * u


# Jitted at module level so that eager calls with the same shapes reuse one compiled program.
@functools.partial(jax.jit, static_argnames="method")
def lag_states(u: Array, a: Array, z0: Array, *, method: str = "auto") -> Array:
    """The lags' states (T, K) for an input `u` (T,), decays `a` (K,) and initial states `z0` (K,).

    **Arguments:** as for [`lag_step`][]; `method` is `"scan"` (sequential), `"associative"`
    (`lax.associative_scan` over the affine maps, O(log T) depth; equal up to rounding) or
    `"auto"`: the scan on a CPU, the associative form on an accelerator.

    **Returns:** (T, K).
    """
    if method == "auto":
        method = "associative" if on_accelerator() else "scan"
    if method == "scan":

        def step(z, ut):
            z = lag_step(z, ut, a)
            return z, z

        _, zs = lax.scan(step, z0, u)
        return zs
    if method == "associative":
        A = jnp.broadcast_to(a, (u.shape[0],) + a.shape)
        B = (1.0 - a) * u[:, None]

        def compose(earlier, later):
            a1, b1 = earlier
            a2, b2 = later
            return a2 * a1, a2 * b1 + b2

        Ac, Bc = lax.associative_scan(compose, (A, B))
        return Ac * z0 + Bc
    raise ValueError(f"unknown lag method {method!r}; choose one of {LAG_METHODS}")


@jax.jit  # one program, not one per operation
def decays(log_time_constants: Array, dt) -> Array:
    """a_k = exp(-dt/τ_k) with τ_k = exp(θ_k): in (0, 1) for every finite θ."""
    return jnp.exp(-dt * jnp.exp(-log_time_constants))


def check_time_constants(time_constants, name: str = "time_constants") -> Array:
    """Positive finite time constants as a vector (K,); `ValueError` (or `eqx.error_if`) if not."""
    tau = jnp.atleast_1d(_checks.as_float_array(time_constants, name))
    if tau.ndim != 1:
        raise ValueError(f"`{name}` must be a vector (K,), got shape {tau.shape}")
    if _checks.is_concrete(tau):
        v = np.asarray(tau)
        if not np.all(np.isfinite(v)) or np.any(v <= 0):
            raise ValueError(f"`{name}` must be positive and finite, got {v.tolist()}")
        return tau
    return eqx.error_if(tau, ~jnp.all(jnp.isfinite(tau) & (tau > 0)), f"`{name}` must be positive and finite")


class Creep(eqx.Module):
    """The creep operator C[u] = Σ_k c_k z_k, z_k a first-order lag of u with time constant τ_k.

    **Arguments:**

    - `time_constants` (K,): τ_k > 0, in the units of `dt` (stored as log τ).
    - `weights` (K,): c_k.
    - `dt`: the sampling interval (> 0).
    - `initial_states`: the lags' states before the first sample, a scalar or (K,); None (the
      default) starts each lag at rest at the first input, z_k[-1] = u_0.
    - `method`: `"scan"` (sequential), `"associative"` (`lax.associative_scan`, O(log T) depth,
      equal up to rounding) or `"auto"` (the default: the scan on a CPU, the associative form on
      an accelerator, where it ran 2,000 times faster on 10^5 samples, `experiments/bench_gpu.py`).

    `__call__` takes one signal (T,); batch with `jax.vmap`. Non-positive time constants or `dt`
    raise `ValueError`.
    """

    log_time_constants: Lags
    weights: Lags
    initial_states: Lags | None
    dt: float = eqx.field(static=True)
    method: str = eqx.field(static=True, default="auto")

    def __init__(self, time_constants, weights, dt, initial_states=None, *, method: str = "auto"):
        if method not in LAG_METHODS:
            raise ValueError(f"unknown lag method {method!r}; choose one of {LAG_METHODS}")
        tau = check_time_constants(time_constants)
        k = tau.shape[0]
        if not (isinstance(dt, (int, float, np.floating, np.integer)) and np.isfinite(dt) and dt > 0):
            raise ValueError(f"`dt` must be a positive finite number, got {dt!r}")
        c = _checks.finite(_checks.per_play(weights, k, "weights"), "weights")
        if c.ndim == 0:
            raise ValueError(f"`weights` must be a vector of {k} entries, got a scalar")
        dtype = jnp.result_type(tau, c)
        self.log_time_constants = jnp.log(tau).astype(dtype)
        self.weights = c.astype(dtype)
        if initial_states is None:
            self.initial_states = None
        else:
            z0 = _checks.finite(_checks.per_play(initial_states, k, "initial_states"), "initial_states")
            self.initial_states = jnp.broadcast_to(z0, (k,)).astype(dtype)
        self.dt = float(dt)
        self.method = method

    @property
    def n_lags(self) -> int:
        """The number of lags K."""
        return self.weights.shape[0]

    @property
    def time_constants(self) -> Lags:
        """τ_k = exp(log τ_k)."""
        return jnp.exp(self.log_time_constants)

    @property
    def decays(self) -> Lags:
        """The per-sample decay factors a_k = exp(-dt/τ_k), each in (0, 1)."""
        return decays(self.log_time_constants, self.dt)

    def _start(self, u: Array) -> Array:
        if self.initial_states is None:
            return jnp.broadcast_to(u[0], self.weights.shape).astype(u.dtype)
        return self.initial_states.astype(u.dtype)

    def states(self, u: SignalLike) -> Float[Array, "time lags"]:
        """The lags' states z (T, K) for the input `u` (T,)."""
        u = _checks.finite(_checks.signal(u), "u")
        u = u.astype(jnp.result_type(u, self.weights))
        return lag_states(u, self.decays.astype(u.dtype), self._start(u), method=self.method)

    def __call__(self, u: SignalLike) -> Signal:
        """The creep output Σ_k c_k z_k (T,) for the input `u` (T,)."""
        return self.states(u) @ self.weights

    def final_states(self, u: SignalLike) -> Lags:
        """The lags' states after the last sample of `u` (to continue a run where it ended)."""
        return self.states(u)[-1]
