"""The normalised gradient estimator (normalised LMS).

Ŵ ← Ŵ + μ h (y − hᵀŴ) / (1 + hᵀh). In the noise-free case the error obeys
W̃ ← (I − μ h hᵀ/(1 + hᵀh)) W̃, whose eigenvalue along h is 1 − μ hᵀh/(1 + hᵀh) ∈ (−1, 1) for
μ ∈ (0, 2): the update is stable for every regressor, and converges when the regressor is
persistently exciting (Definition 1), at a rate set by μ and the PE level c1.
"""

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array

from .. import _checks
from .._custom_types import Gram, Scalar, Weights
from .estimators import AbstractEstimator


class _GradientState(eqx.Module):
    weights: Weights
    error: Scalar


class NormalisedGradient(AbstractEstimator):
    """Normalised gradient descent on the squared prediction error.

    **Arguments:** `gain`, the step size μ in (0, 2) (default 1).
    """

    gain_: Array

    def __init__(self, gain=1.0):
        mu = _checks.as_float_array(gain, "gain")
        if mu.ndim != 0:
            raise ValueError(f"`gain` must be a scalar, got shape {mu.shape}")
        msg = "the normalised gradient gain must be in (0, 2) for stability"
        if _checks.is_concrete(mu):
            if not (0 < float(mu) < 2):
                raise ValueError(f"{msg}, got {float(mu)}")
        else:
            mu = eqx.error_if(mu, ~((mu > 0) & (mu < 2)), msg)
        self.gain_ = mu

    @property
    def n_plays(self) -> int | None:
        return None

    def init(self, initial_weights: Weights) -> _GradientState:
        w0 = jnp.asarray(initial_weights)
        return _GradientState(w0, jnp.zeros((), w0.dtype))

    def step(self, state: _GradientState, h, y) -> _GradientState:
        mu = self.gain_.astype(state.weights.dtype)
        e = y - jnp.dot(h, state.weights)
        w = state.weights + (mu * e / (1 + jnp.dot(h, h))) * h
        return _GradientState(w, e)

    def weights(self, state: _GradientState) -> Weights:
        return state.weights

    def gain(self, state: _GradientState) -> Gram:
        n = state.weights.shape[0]
        return self.gain_.astype(state.weights.dtype) * jnp.eye(n, dtype=state.weights.dtype)

    def prediction_error(self, state: _GradientState) -> Scalar:
        return state.error
