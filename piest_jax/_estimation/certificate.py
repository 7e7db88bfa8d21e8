"""Closed-form information solution of the continuous-time RLS, and a convergence certificate.

With zero-order-hold data, the continuous RLS of the paper has the closed form

    R_k = P0⁻¹ + A_k,   A_k = Σ_{i<=k} c_i h_i h_iᵀ,   c_i = dt / m_i²,
    Ŵ_k = R_k⁻¹ (P0⁻¹ Ŵ0 + Σ_{i<=k} c_i h_i y_i).

Without noise y = hᵀW, so R_k W̃_k = P0⁻¹ W̃_0 for the error W̃ = Ŵ − W, hence

    ‖W̃_k‖ <= ‖W̃_0‖ · λ_max(P0⁻¹) / (λ_min(P0⁻¹) + λ_min(A_k)).

Both bounds below need only the regressor (the input and the thresholds), not the output: they
are known before the estimator runs. The Gram bound uses λ_min(A_k) itself; the PE bound uses
Definition 1 alone: each completed disjoint window of w samples adds at least
w·dt·c1 / max m² to λ_min(A_k).
"""

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from .. import _checks
from .._custom_types import Gram, Regressor, Scalar, Signal, SignalLike, Weights
from .._excitation.pe import _pe_levels, _regressor, _window_args
from .rls import NORMALISATIONS, Normalisation, check_p0, sample_weight, sqrt_p0


def _check_dt(dt, normalisation: str) -> Array:
    if normalisation not in NORMALISATIONS:
        raise ValueError(f"unknown normalisation {normalisation!r}; choose one of {NORMALISATIONS}")
    dt = _checks.as_float_array(dt, "dt")
    if dt.ndim != 0:
        raise ValueError(f"`dt` must be a scalar, got shape {dt.shape}")
    if _checks.is_concrete(dt) and not (bool(jnp.isfinite(dt)) and float(dt) > 0):
        raise ValueError(f"`dt` must be positive and finite, got {float(dt)}")
    return dt


def _check_p0_for(P0, n: int) -> Array:
    P0 = check_p0(P0)
    if P0.ndim == 2 and P0.shape[0] != n:
        raise ValueError(f"`P0` is {P0.shape} but the regressor `H` has {n} columns")
    return P0


def _p0_matrix(P0, n, dtype):
    S0 = sqrt_p0(P0, n, dtype)
    return S0 @ S0.T


def information_form(
    H: Regressor,
    y: SignalLike,
    P0,
    dt,
    *,
    normalisation: Normalisation = "paper",
    initial_weights: Weights | None = None,
) -> Float[Array, "time n"]:
    """The continuous-time RLS estimate at every sample, from the closed-form information solution.

    Computed by cumulative sums and one linear solve per sample in the whitened form
    Ŵ_k = Ŵ0 + L (I + Lᵀ A_k L)⁻¹ Lᵀ (b_k − A_k Ŵ0), P0 = L Lᵀ, which is well conditioned
    (its eigenvalues are >= 1). It is the reference for [`ContinuousRLS`][]'s sequential scan.

    **Arguments:** `H` (T, n), `y` (T,), `P0` (scalar or (n, n)), `dt`; `normalisation` and
    `initial_weights` as in `ContinuousRLS` / `estimate`.

    **Returns:** (T, n), the estimate after each sample.
    """
    H = _regressor(H)
    T, n = H.shape
    y = _checks.finite(_checks.signal(y, "y"), "y").astype(H.dtype)
    if y.shape[0] != T:
        raise ValueError(f"`y` has {y.shape[0]} samples but the regressor `H` has {T}")
    P0 = _check_p0_for(P0, n)
    w0 = jnp.zeros(n, H.dtype) if initial_weights is None else jnp.asarray(initial_weights, H.dtype)
    if w0.shape != (n,):
        raise ValueError(f"`initial_weights` has shape {w0.shape} but `H` has {n} columns")
    return _information(H, y, P0, _check_dt(dt, normalisation), w0, normalisation)


@eqx.filter_jit
def _information(H, y, P0, dt, w0, normalisation: str):
    n = H.shape[1]
    c = _sample_weights(H, dt, normalisation)
    A = jnp.cumsum(c[:, None, None] * H[:, :, None] * H[:, None, :], axis=0)
    b = jnp.cumsum((c * y)[:, None] * H, axis=0)
    L = sqrt_p0(P0, n, H.dtype)
    M = jnp.eye(n, dtype=H.dtype) + jnp.einsum("ji,tjk,kl->til", L, A, L)
    rhs = jnp.einsum("ji,tj->ti", L, b - A @ w0)
    z = jnp.linalg.solve(M, rhs[..., None])[..., 0]
    return w0 + z @ L.T


def _sample_weights(H: Regressor, dt, normalisation: str) -> Signal:
    """c_k = dt / m_k² for every row of H."""
    return jax.vmap(lambda h: sample_weight(h, dt, normalisation))(H).astype(H.dtype)


def noise_covariance(H: Regressor, P0, dt, noise_std, *, normalisation: Normalisation = "paper") -> Gram:
    """Covariance of the final `ContinuousRLS` estimate when white noise is added to y.

    From the closed form, Ŵ_T − E[Ŵ_T] = R_T⁻¹ Σ_k c_k h_k ε_k, so for ε_k ~ N(0, σ²)

        Cov(Ŵ_T) = σ² R_T⁻¹ (Σ_k c_k² h_k h_kᵀ) R_T⁻¹,   R_T = P0⁻¹ + Σ_k c_k h_k h_kᵀ,

    and the mean is the noise-free estimate (which the certificate bounds). It is the reference
    for the Monte Carlo spread of the batch experiments.

    **Arguments:** `H` (T, n); `P0`, `dt`, `normalisation` as in `ContinuousRLS`; `noise_std` σ.

    **Returns:** (n, n), the covariance of the estimate after the last sample.
    """
    H = _regressor(H)
    _, n = H.shape
    P0 = _check_p0_for(P0, n)
    c = _sample_weights(H, _check_dt(dt, normalisation), normalisation)
    R = jnp.linalg.inv(_p0_matrix(P0, n, H.dtype)) + jnp.einsum("t,ti,tj->ij", c, H, H)
    Q = jnp.einsum("t,ti,tj->ij", c**2, H, H)
    Rinv = jnp.linalg.inv(R)
    sigma = _checks.as_float_array(noise_std, "noise_std")
    if sigma.ndim != 0:
        raise ValueError(f"`noise_std` must be a scalar, got shape {sigma.shape}")
    if _checks.is_concrete(sigma) and not float(sigma) >= 0:
        raise ValueError(f"`noise_std` must be non-negative, got {float(sigma)}")
    cov = sigma.astype(H.dtype) ** 2 * (Rinv @ Q @ Rinv)
    return 0.5 * (cov + cov.T)


class Certificate(eqx.Module):
    """Predicted bounds on ‖Ŵ_k − W‖ / ‖Ŵ_0 − W‖ (noise-free), see [`convergence_certificate`][].

    **Fields:** `gram_bound` (T,) from the accumulated information; `pe_bound` (T,) from the PE
    level alone; `c1`, the PE level over windows of `window` samples; `max_m2`, the largest m².
    """

    gram_bound: Signal
    pe_bound: Signal
    c1: Scalar
    max_m2: Scalar
    window: int = eqx.field(static=True)


def convergence_certificate(
    H: Regressor, P0, dt, window: int, *, normalisation: Normalisation = "paper"
) -> Certificate:
    """Bound the relative weight error of `ContinuousRLS` over time, before running it.

    **Arguments:**

    - `H`: the regressor (T, n), known from the input and the thresholds.
    - `P0`, `dt`, `normalisation`: the estimator's settings.
    - `window`: the PE window T0 / dt in samples.

    **Returns:** a [`Certificate`][]; multiply its bounds by ‖Ŵ_0 − W‖ for absolute bounds.
    The estimator's noise-free error stays below `gram_bound`, which stays below `pe_bound`.
    """
    H = _regressor(H)
    _, n = H.shape
    P0 = _check_p0_for(P0, n)
    dt = _check_dt(dt, normalisation)
    window, _, _ = _window_args(H.shape[0], window, 1)  # a clear error for a bad window, before compiling
    return _certificate(H, P0, dt, window, normalisation)


@eqx.filter_jit
def _certificate(H, P0, dt, window: int, normalisation: str) -> Certificate:
    T, n = H.shape
    c = _sample_weights(H, dt, normalisation)
    A = jnp.cumsum(c[:, None, None] * H[:, :, None] * H[:, None, :], axis=0)
    r0 = jnp.linalg.eigvalsh(jnp.linalg.inv(_p0_matrix(P0, n, H.dtype)))
    lam_a = jnp.maximum(jnp.linalg.eigvalsh(A)[:, 0], 0.0)
    gram_bound = r0[-1] / (r0[0] + lam_a)
    # The core, not `pe_level`: H was checked before this program, and a check of a traced value
    # would be a host callback, which keeps the program out of the persistent compilation cache.
    c1 = jnp.maximum(jnp.min(_pe_levels(H, window, 1)), 0.0)
    hh = jnp.sum(H * H, axis=1)
    m2 = (1 + hh) ** 2 if normalisation == "paper" else 1 + hh
    max_m2 = jnp.max(m2)
    completed = (jnp.arange(T) + 1) // window
    lam_pe = completed * window * dt * c1 / max_m2
    pe_bound = r0[-1] / (r0[0] + lam_pe)
    return Certificate(gram_bound, pe_bound, c1, max_m2, window)
