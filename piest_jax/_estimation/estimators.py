"""Online weight estimation: the estimator interface and the thin scan that runs one.

An estimator is an `eqx.Module` holding its settings; `init(initial_weights)` gives a typed state
and `step(state, h, y)` consumes one sample (regressor row h (n,), measured output y). The scan in
[`estimate`][] returns the trajectories a user looks at: the estimate, the a-priori prediction error
y_k − h_kᵀŴ_{k−1}, and the trace and extreme eigenvalues of the gain matrix.

Concrete estimators: `ContinuousRLS` and `ForgettingRLS` in `_rls.py`, `NormalisedGradient` in
`_gradient.py`.
"""

import abc

import equinox as eqx
import jax.numpy as jnp
from jax import lax
from jaxtyping import Array, Float

from .. import _checks
from .._custom_types import Gram, Regressor, Scalar, Signal, SignalLike, Weights


class AbstractEstimator(eqx.Module):
    """Online estimator of the weights W in y = hᵀW.

    Subclasses provide `init`, `step`, `weights` and `gain`; batching over settings or data is the
    caller's `jax.vmap` (array-valued settings such as `P0` or a forgetting factor may be batched).
    """

    @abc.abstractmethod
    def init(self, initial_weights: Weights):
        """The state before the first sample, for the initial estimate (n,)."""

    @abc.abstractmethod
    def step(self, state, h: Weights, y: Scalar):
        """Consume one sample: regressor row `h` (n,) and output `y`; returns the new state."""

    @abc.abstractmethod
    def weights(self, state) -> Weights:
        """The current estimate Ŵ (n,)."""

    @abc.abstractmethod
    def gain(self, state) -> Gram:
        """The current gain matrix (P for least squares), (n, n)."""

    @abc.abstractmethod
    def prediction_error(self, state) -> Scalar:
        """The a-priori prediction error of the last sample consumed."""

    @property
    @abc.abstractmethod
    def n_plays(self) -> int | None:
        """The number of weights fixed by the settings, or None when any n is accepted."""


class Estimation(eqx.Module):
    """Trajectories returned by [`estimate`][]; row k is after consuming sample k.

    **Fields:** `weights` (T, n); `error` (T,), the a-priori prediction error y_k − h_kᵀŴ_{k−1};
    `gain_trace`, `gain_min_eig`, `gain_max_eig` (T,), of the gain matrix (P for least squares;
    1 / gain_max_eig is the smallest eigenvalue of the information matrix P⁻¹).
    """

    weights: Float[Array, "time n"]
    error: Signal
    gain_trace: Signal
    gain_min_eig: Signal
    gain_max_eig: Signal


def check_estimator(estimator) -> AbstractEstimator:
    """Refuse anything but an estimator instance, naming the usual slip: the class itself."""
    if isinstance(estimator, type) and issubclass(estimator, AbstractEstimator):
        raise ValueError(
            f"`estimator` is the class {estimator.__name__}, not an estimator: create one with its "
            f"settings, e.g. {estimator.__name__}(...)"
        )
    if not isinstance(estimator, AbstractEstimator):
        raise ValueError(
            f"`estimator` must be an estimator such as ContinuousRLS(P0, dt), got {type(estimator).__name__}"
        )
    return estimator


def _data(estimator: AbstractEstimator, H, y, initial_weights) -> tuple[Array, Array, Array]:
    check_estimator(estimator)
    H = _checks.as_float_array(H, "H")
    if H.ndim != 2:
        raise ValueError(f"`H` must be one regressor of shape (T, n), got shape {H.shape}; batch several with jax.vmap")
    T, n = H.shape
    if T < 1 or n < 1:
        raise ValueError(f"`H` is empty: shape {H.shape}")
    y = _checks.signal(y, "y")
    if y.shape[0] != T:
        raise ValueError(f"`y` has {y.shape[0]} samples but the regressor `H` has {T}")
    expected = estimator.n_plays
    if expected is not None and expected != n:
        raise ValueError(
            f"the estimator is set up for {expected} plays (from P0) but the regressor `H` has "
            f"{n} columns: thresholds and regressor do not match"
        )
    if initial_weights is None:
        w0 = jnp.zeros(n, H.dtype)
    else:
        w0 = _checks.as_float_array(initial_weights, "initial_weights")
        if w0.shape != (n,):
            raise ValueError(f"`initial_weights` has shape {w0.shape} but the regressor `H` has {n} columns")
    dtype = jnp.result_type(H, y, w0)
    H = _checks.finite(H, "H").astype(dtype)
    y = _checks.finite(y, "y").astype(dtype)
    w0 = _checks.finite(w0, "initial_weights").astype(dtype)
    return H, y, w0


def estimate(
    estimator: AbstractEstimator,
    H: Regressor,
    y: SignalLike,
    initial_weights: Weights | None = None,
    *,
    rescale: bool = False,
) -> Estimation:
    """Run an estimator over a record: a thin `lax.scan` of `estimator.step`.

    **Arguments:**

    - `estimator`: e.g. `ContinuousRLS(P0=1e9, dt=1e-3)`.
    - `H`: the regressor (T, n), e.g. `PIOperator(r, w).regressor(u)`.
    - `y`: the measured output (T,).
    - `initial_weights`: Ŵ(0), (n,); zeros by default.
    - `rescale`: estimate on H / a and y / b, with a = max |H| and b = max |y| over the
      record, and report everything in the user's units (weights × b / a, errors × b, gains
      / a²). The settings (P0, gains, a trace limit) then refer to data of magnitude one, so the
      same settings give the same answer, down to rounding, whether u and y are in microvolts or
      kilovolts. Without it the settings are in the data's units: the normalisation
      m = 1 + hᵀh of `ContinuousRLS` and `NormalisedGradient` is not scale-free, and a P0 chosen
      for unit data barely moves the estimate of data at 1e-6. The scales use the whole record
      (an offline choice); online, fix them from the sensors' ranges.

    **Returns:** an [`Estimation`][] with the trajectories.

    NaN or inf in the data, or shapes that do not match, raise `ValueError` (under `jit`, an
    `eqx.error_if` runtime error).
    """
    H, y, w0 = _data(estimator, H, y, initial_weights)
    if not rescale:
        return _scan(estimator, H, y, w0)
    a, b = _peak(H), _peak(y)
    e = _scan(estimator, H / a, y / b, w0 * (a / b))
    g = 1 / (a * a)
    return Estimation(e.weights * (b / a), e.error * b, e.gain_trace * g, e.gain_min_eig * g, e.gain_max_eig * g)


def _peak(x: Array) -> Array:
    # All-zero data (an output that never moves, a play that is never excited) keeps unit scale.
    m = jnp.max(jnp.abs(x))
    return jnp.where(m > 0, m, jnp.ones_like(m))


# Compiled once per estimator type, static settings and data shape; the settings' values (P0, dt,
# λ, ...) are traced, so sweeping them does not recompile.
@eqx.filter_jit
def _scan(estimator: AbstractEstimator, H, y, w0) -> Estimation:
    def body(state, hy):
        h, yk = hy
        state = estimator.step(state, h, yk)
        P = estimator.gain(state)
        eig = jnp.linalg.eigvalsh(P)
        out = (estimator.weights(state), estimator.prediction_error(state), jnp.trace(P))
        return state, out + (eig[0], eig[-1])

    _, (w, e, tr, lo, hi) = lax.scan(body, estimator.init(w0), (H, y))
    return Estimation(w, e, tr, lo, hi)
