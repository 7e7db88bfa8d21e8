"""Recursive least squares: the paper's continuous-time RLS and a discrete RLS with forgetting.

**Continuous-time RLS (paper eqs. 5-6).** Ŵ' = P h (y − hᵀŴ)/m², P' = −P h hᵀ P/m², P(0) = P0.
Written for the information matrix R = P⁻¹ these are linear:

    dR/dt = h hᵀ / m²,        d(R Ŵ)/dt = h y / m²,

so with the sampled data held constant over each step (zero-order hold) one step of length dt
adds exactly c·h hᵀ and c·h y, c = dt / m². The Sherman-Morrison identity turns that exact step into
a rank-one covariance update, which we carry as a square-root factor P = S Sᵀ (Potter's form):

    f = √c Sᵀh,  α = 1 + fᵀf,  Ŵ ← Ŵ + √c S f (y − hᵀŴ)/α,  S ← S − S f fᵀ / (α + √α).

P stays symmetric positive semi-definite by construction, nothing is inverted, and no step can
overshoot, so the update is stable for any P0 (1e12 and beyond) and any dt; plain explicit Euler
on P is not (with P0 = 1e6·I and dt = 1 ms it diverges). The result equals the closed-form
information solution Ŵ_k = (P0⁻¹ + Σ c h hᵀ)⁻¹(P0⁻¹Ŵ0 + Σ c h y) (see `information_form`).

Normalisation: `"paper"` uses m = 1 + hᵀh and divides by m² = (1 + hᵀh)², as printed in the
paper; `"standard"` uses the more common m² = 1 + hᵀh (Ioannou & Sun), which weights each sample
more and so converges faster for the same P0.

**Discrete RLS with forgetting.** e = y − hᵀŴ, Ŵ ← Ŵ + P h e/(λ + hᵀPh),
P ← (P − P h hᵀP/(λ + hᵀPh))/λ, also in square-root form. With λ < 1 and a regressor that stops
exciting, P grows without bound (wind-up); `windup="trace"` rescales P so that its trace never
exceeds `max_trace`, `windup="reset"` restarts from P0 when it does.
"""

from typing import Literal

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

from .. import _checks
from .._custom_types import Gram, Scalar, Weights
from .estimators import AbstractEstimator

Normalisation = Literal["paper", "standard"]
NORMALISATIONS: tuple[Normalisation, ...] = ("paper", "standard")
WINDUPS = ("trace", "reset", "none")


class _RLSState(eqx.Module):
    weights: Weights
    sqrt_gain: Float[Array, "n n"]
    error: Scalar


def check_p0(P0, name: str = "P0") -> Array:
    """P0 as a positive scalar (meaning P0·I) or a symmetric positive definite (n, n) matrix."""
    P0 = _checks.as_float_array(P0, name)
    if P0.ndim == 0:
        if _checks.is_concrete(P0):
            if not (bool(jnp.isfinite(P0)) and float(P0) > 0):
                raise ValueError(f"`{name}` must be positive definite: got the scalar {float(P0)}")
            return P0
        return eqx.error_if(P0, ~(jnp.isfinite(P0) & (P0 > 0)), f"`{name}` must be positive")
    if P0.ndim != 2 or P0.shape[0] != P0.shape[1]:
        raise ValueError(f"`{name}` must be a positive scalar or a square matrix, got {P0.shape}")
    if _checks.is_concrete(P0):
        import numpy as np

        p = np.asarray(P0, dtype=np.float64)
        if not np.all(np.isfinite(p)):
            raise ValueError(f"`{name}` contains NaN or inf")
        if not np.allclose(p, p.T, rtol=1e-6, atol=0.0):
            raise ValueError(f"`{name}` must be symmetric positive definite: it is not symmetric")
        if np.linalg.eigvalsh(p)[0] <= 0:
            raise ValueError(
                f"`{name}` must be symmetric positive definite: smallest eigenvalue {np.linalg.eigvalsh(p)[0]:.3g}"
            )
        return P0
    bad = ~jnp.all(jnp.isfinite(P0)) | (jnp.linalg.eigvalsh(P0)[0] <= 0)
    return eqx.error_if(P0, bad, f"`{name}` must be symmetric positive definite")


def sqrt_p0(P0: Array, n: int, dtype) -> Array:
    """A factor S0 with S0 S0ᵀ = P0 (n, n)."""
    if P0.ndim == 0:
        return jnp.sqrt(P0).astype(dtype) * jnp.eye(n, dtype=dtype)
    return jnp.linalg.cholesky(P0.astype(dtype))


def sample_weight(h: Array, dt, normalisation: str) -> Array:
    """c = dt / m² for one regressor row, under either normalisation."""
    hh = jnp.dot(h, h)
    m2 = (1 + hh) ** 2 if normalisation == "paper" else 1 + hh
    return dt / m2


def _potter(S: Array, f: Array, lam) -> tuple[Array, Array, Array]:
    """Square-root rank-one downdate: returns (S f, α, S') with S'S'ᵀ = S(I − f fᵀ/α)Sᵀ/λ."""
    alpha = lam + jnp.dot(f, f)
    Sf = S @ f
    S_new = (S - jnp.outer(Sf, f) / (alpha + jnp.sqrt(lam * alpha))) / jnp.sqrt(lam)
    return Sf, alpha, S_new


class ContinuousRLS(AbstractEstimator):
    """The paper's continuous-time RLS (eqs. 5-6), integrated exactly on sampled data.

    **Arguments:**

    - `P0`: initial gain, a positive scalar (P0·I) or an SPD (n, n) matrix.
    - `dt`: the sampling step in seconds.
    - `normalisation`: `"paper"` (m = 1 + hᵀh, divide by m²) or `"standard"` (m² = 1 + hᵀh).

    See the module docstring for the update and why it is stable for any P0 and dt.
    """

    P0: Array
    dt: Array
    normalisation: str = eqx.field(static=True)

    def __init__(self, P0, dt, *, normalisation: Normalisation = "paper"):
        if normalisation not in NORMALISATIONS:
            raise ValueError(f"unknown normalisation {normalisation!r}; choose one of {NORMALISATIONS}")
        self.P0 = check_p0(P0)
        dt = _checks.as_float_array(dt, "dt")
        if dt.ndim != 0:
            raise ValueError(f"`dt` must be a scalar, got shape {dt.shape}")
        if _checks.is_concrete(dt):
            if not (float(dt) > 0 and bool(jnp.isfinite(dt))):
                raise ValueError(f"`dt` must be positive and finite, got {float(dt)}")
        else:
            dt = eqx.error_if(dt, ~((dt > 0) & jnp.isfinite(dt)), "`dt` must be positive and finite")
        self.dt = dt
        self.normalisation = normalisation

    @property
    def n_plays(self) -> int | None:
        return None if self.P0.ndim == 0 else self.P0.shape[0]

    def init(self, initial_weights: Weights) -> _RLSState:
        w0 = jnp.asarray(initial_weights)
        S0 = sqrt_p0(self.P0, w0.shape[0], w0.dtype)
        return _RLSState(w0, S0, jnp.zeros((), w0.dtype))

    def step(self, state: _RLSState, h, y) -> _RLSState:
        dtype = state.weights.dtype
        sc = jnp.sqrt(sample_weight(h, self.dt, self.normalisation)).astype(dtype)
        e = y - jnp.dot(h, state.weights)
        f = sc * (state.sqrt_gain.T @ h)
        Sf, alpha, S = _potter(state.sqrt_gain, f, jnp.ones((), dtype))
        w = state.weights + (sc * e / alpha) * Sf
        return _RLSState(w, S, e)

    def weights(self, state: _RLSState) -> Weights:
        return state.weights

    def gain(self, state: _RLSState) -> Gram:
        return state.sqrt_gain @ state.sqrt_gain.T

    def prediction_error(self, state: _RLSState) -> Scalar:
        return state.error


class ForgettingRLS(AbstractEstimator):
    """Discrete-time RLS with forgetting factor λ and protection against covariance wind-up.

    **Arguments:**

    - `P0`: initial gain, a positive scalar or an SPD (n, n) matrix.
    - `forgetting`: λ in (0, 1]; 1 is ordinary least squares, smaller values track changes faster
      and average noise less.
    - `windup`: `"trace"` (default) caps trace P at `max_trace` by rescaling, `"reset"` returns
      to P0 when trace P exceeds `max_trace`, `"none"` leaves P alone.
    - `max_trace`: the cap; default trace P0.
    """

    P0: Array
    forgetting: Array
    max_trace: Array | None
    windup: str = eqx.field(static=True)

    def __init__(self, P0, forgetting=1.0, *, windup: str = "trace", max_trace=None):
        if windup not in WINDUPS:
            raise ValueError(f"unknown windup protection {windup!r}; choose one of {WINDUPS}")
        self.P0 = check_p0(P0)
        lam = _checks.as_float_array(forgetting, "forgetting")
        if lam.ndim != 0:
            raise ValueError(f"`forgetting` must be a scalar, got shape {lam.shape}")
        msg = "forgetting factor must be in (0, 1]"
        if _checks.is_concrete(lam):
            if not (0 < float(lam) <= 1):
                raise ValueError(f"{msg}, got {float(lam)}")
        else:
            lam = eqx.error_if(lam, ~((lam > 0) & (lam <= 1)), msg)
        self.forgetting = lam
        if max_trace is not None:
            max_trace = _checks.as_float_array(max_trace, "max_trace")
            if _checks.is_concrete(max_trace) and not float(max_trace) > 0:
                raise ValueError(f"`max_trace` must be positive, got {float(max_trace)}")
        self.max_trace = max_trace
        self.windup = windup

    @property
    def n_plays(self) -> int | None:
        return None if self.P0.ndim == 0 else self.P0.shape[0]

    def init(self, initial_weights: Weights) -> _RLSState:
        w0 = jnp.asarray(initial_weights)
        S0 = sqrt_p0(self.P0, w0.shape[0], w0.dtype)
        return _RLSState(w0, S0, jnp.zeros((), w0.dtype))

    def step(self, state: _RLSState, h, y) -> _RLSState:
        dtype = state.weights.dtype
        lam = self.forgetting.astype(dtype)
        e = y - jnp.dot(h, state.weights)
        f = state.sqrt_gain.T @ h
        Sf, alpha, S = _potter(state.sqrt_gain, f, lam)
        w = state.weights + (e / alpha) * Sf
        if self.windup != "none":
            n = w.shape[0]
            S0 = sqrt_p0(self.P0, n, dtype)
            cap = jnp.sum(S0**2) if self.max_trace is None else self.max_trace.astype(dtype)
            tr = jnp.sum(S**2)
            if self.windup == "trace":
                S = S * jnp.sqrt(jnp.minimum(1.0, cap / tr))
            else:
                S = jnp.where(tr > cap, S0, S)
        return _RLSState(w, S, e)

    def weights(self, state: _RLSState) -> Weights:
        return state.weights

    def gain(self, state: _RLSState) -> Gram:
        return state.sqrt_gain @ state.sqrt_gain.T

    def prediction_error(self, state: _RLSState) -> Scalar:
        return state.error
