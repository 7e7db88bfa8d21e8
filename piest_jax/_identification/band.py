"""Prediction bands: how far a fitted model's output on an input is uncertain, from the fit's
parameter covariance.

Linearised at the fitted parameters θ̂, a prediction ŷ_t(θ) on an input u has variance
J_t Σ J_tᵀ, with J_t the row of the Jacobian of the prediction on u with respect to θ and Σ the
fit's covariance ([`fit_pi`][]'s, Newey-West or Gauss-Newton). The prediction's standard error
is sqrt(J_t Σ J_tᵀ) per sample; a new measurement at that sample also carries the residual
noise, sqrt(J_t Σ J_tᵀ + σ²) with σ the fit's `residual_std`.

J comes from the same model and scan the fit and its covariance use (`covariance.chunk_rows`):
forward-mode sensitivities carried through the input chunk by chunk, so only one chunk's rows
(p x chunk) exist at a time and the band's memory does not grow with the input's length.
"""

import statistics

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jax import lax

from .. import _checks
from .._custom_types import Scalar, Signal, SignalLike
from . import covariance as _cov
from .band_saturating import band_parts
from .fit import PIFit, run
from .fit_data import Scales
from .fit_gpi import GPIFit
from .fit_preisach import PreisachFit


class PredictionBand(eqx.Module):
    """The result of [`prediction_band`][].

    **Fields:**

    - `prediction` (T,): the model's output on the input (the fit's own prediction).
    - `std_error` (T,): the standard error of that prediction from the parameters' covariance
      (the band of the noiseless output).
    - `residual_std`: σ, the fit's residuals' standard deviation (the noise of one measurement).
    """

    prediction: Signal
    std_error: Signal
    residual_std: Scalar

    @property
    def measurement_std_error(self) -> Signal:
        """sqrt(std_error² + σ²) (T,): the standard error of a new measurement at each sample."""
        return jnp.sqrt(self.std_error**2 + self.residual_std**2)

    def interval(self, level: float = 0.95, *, measurement: bool = True):
        """The two-sided band at `level` (normal quantiles): `(lower, upper)`, (T,) each.

        **Arguments:** `level` in (0, 1); `measurement`: the band of a new measurement (True,
        the default) or of the noiseless output (False).

        **Returns:** `(lower, upper)`, the prediction ∓ z · standard error.
        """
        if not 0 < level < 1:
            raise ValueError(f"`level` must lie strictly between 0 and 1, got {level!r}")
        z = statistics.NormalDist().inv_cdf(0.5 + 0.5 * level)
        se = self.measurement_std_error if measurement else self.std_error
        return self.prediction - z * se, self.prediction + z * se

    def coverage(self, y: SignalLike, level: float = 0.95, *, measurement: bool = True) -> float:
        """The fraction of the samples of `y` (T,) inside the band at `level`.

        **Arguments:** `y`, measured (or noiseless, with `measurement=False`) outputs on the same
        input; `level`, `measurement` as in `interval`.

        **Returns:** a float in [0, 1]; about `level` when the band is calibrated.
        """
        y = np.asarray(_checks.finite(_checks.signal(y, "y"), "y"))
        if y.shape != self.prediction.shape:
            raise ValueError(f"`y` has {y.shape[0]} samples but the band {self.prediction.shape[0]}")
        lower, upper = (np.asarray(a) for a in self.interval(level, measurement=measurement))
        return float(np.mean((y >= lower) & (y <= upper)))


def prediction_band(
    fit: PIFit | GPIFit | PreisachFit,
    u: SignalLike,
    *,
    initial_states=None,
    lag_states=None,
    offset=None,
    chunk: int = _cov.CHUNK,
) -> PredictionBand:
    """The linearised prediction band of a fitted model on an input.

    Per sample, the prediction's standard error sqrt(J_t Σ J_tᵀ), J_t the Jacobian of the
    prediction at sample t with respect to the fitted parameters and Σ `fit.covariance`, and the
    residual standard deviation σ that a new measurement adds (see [`PredictionBand`][]).

    Parameters the record does not determine through the Jacobian's rank add nothing: the fit's
    covariance is the pseudo-inverse on the determined subspace, so their directions are
    excluded, and the band is that of the determined combinations (it can be too narrow on an
    input that moves those parameters, e.g. one reaching a play the record never excited).
    Parameters undetermined by the relative limit (a standard error beyond half their scale)
    count with their large standard errors. States or an offset given here are taken as known:
    their parameters, if fitted, add nothing either.

    **Arguments:**

    - `fit`: a [`PIFit`][] with a covariance (not `covariance=None`), or a
      [`GPIFit`][piest_jax.GPIFit] or [`PreisachFit`][piest_jax.PreisachFit] with one
      (`band_saturating.py`; no `lag_states` or `offset` then).
    - `u`: the input (T,).
    - `initial_states`: the plays' states before the first sample (scalar or (n,)), as
      `fit(u, initial_states)` takes them; default the fitted ones.
    - `lag_states`: the creep lags' states (scalar or (K,)); default the fitted ones, or at rest
      at u_0 when they were not fitted.
    - `offset`: the output offset; default the fitted one.
    - `chunk`: samples per chunk of the Jacobian's rows (memory p x `chunk`).

    **Returns:** a [`PredictionBand`][]; its `prediction` is `fit(u, initial_states)` (with the
    given lag states and offset). Raises `ValueError` for a fit without a covariance, a
    non-finite or empty input, states of the wrong size or a non-positive `chunk`.
    """
    if not isinstance(fit, PIFit | GPIFit | PreisachFit):
        raise ValueError(
            "`fit` must be a PIFit, GPIFit or PreisachFit (from fit_pi, fit_gpi, "
            f"fit_preisach), got {type(fit).__name__}"
        )
    if fit.covariance is None or fit.residual_std is None:
        raise ValueError("the fit has no covariance: fit it with `covariance` 'newey-west' or 'gauss-newton', not None")
    if not _checks.is_whole(chunk) or chunk < 1:
        raise ValueError(f"`chunk` must be a positive whole number, got {chunk!r}")
    u = _checks.finite(_checks.signal(u, "u"), "u")
    if isinstance(fit, GPIFit | PreisachFit):
        if lag_states is not None or offset is not None:
            raise ValueError(
                f"a {type(fit).__name__} has no creep or separate offset: give neither `lag_states` nor `offset`"
            )
        pred, var, sigma = band_parts(fit, u, initial_states, chunk)
        return PredictionBand(pred, jnp.sqrt(jnp.maximum(var, 0.0)), sigma)
    dtype = jnp.result_type(u, fit.weights)
    u = u.astype(dtype)
    n, k = fit.n_plays, fit.n_lags
    fitted_states = any("initial_states" in name for name in fit.parameter_names)
    layout = _cov.Layout(n, k, fitted_states)
    names, index = layout.names(n, k)
    if names != tuple(fit.parameter_names):
        raise ValueError("the fit's parameters do not match its model's; was it changed after fit_pi?")
    x0 = _states(fit.initial_states if initial_states is None else initial_states, n, "initial_states", dtype)
    taus = weights_c = z0 = None
    if k:
        c = fit.creep
        assert c is not None  # n_lags counts the creep's lags
        taus, weights_c = c.time_constants, c.weights
        default_z = u[0] if c.initial_states is None else c.initial_states
        z0 = _states(default_z if lag_states is None else lag_states, k, "lag_states", dtype)
    elif lag_states is not None:
        raise ValueError("`lag_states` given, but the fit has no creep")
    c0 = fit.offset if offset is None else offset
    theta = _cov.flatten(layout, fit.thresholds.astype(dtype), fit.weights.astype(dtype), c0, x0, taus, weights_c, z0)
    # Σ over every parameter of the layout; given states and offset are known (no variance).
    P = theta.shape[0]
    cov = np.zeros((P, P))
    cov[np.ix_(index, index)] = np.asarray(fit.covariance, np.float64)
    known = [
        name.startswith("initial_states")
        and initial_states is not None
        or name.startswith("creep.initial_states")
        and lag_states is not None
        or name == "offset"
        and offset is not None
        for name in names
    ]
    cov[index[np.asarray(known, bool)]] = 0.0
    cov[:, index[np.asarray(known, bool)]] = 0.0
    one = jnp.ones((), dtype)
    s = Scales(0 * one, one, 0 * one, one)  # the data's units throughout
    dt = one if fit.creep is None else jnp.asarray(fit.creep.dt, dtype)
    pred, var = _band(layout, theta, jnp.asarray(cov, dtype), u, s, x0, z0, dt, min(int(chunk), u.shape[0]))
    return PredictionBand(pred, jnp.sqrt(jnp.maximum(var, 0.0)), jnp.asarray(fit.residual_std, dtype))


def _states(x, m, name, dtype):
    x = jnp.asarray(x, dtype)
    if x.ndim > 1 or x.ndim == 1 and x.shape[0] != m:
        raise ValueError(f"`{name}` must be a scalar or have {m} entries, got shape {x.shape}")
    return _checks.finite(jnp.broadcast_to(x, (m,)), name)


@eqx.filter_jit
def _band(layout, theta, cov, u, s, x0, z0, dt, chunk: int):
    """The prediction (T,) and its variance diag(J Σ Jᵀ) (T,), J's rows a chunk at a time."""
    T = u.shape[0]
    s0, ds0, rows = _cov.chunk_rows(run, layout, theta, s, x0, z0, dt)

    def body(carry, uu):
        states, dstates = carry
        pred, after, J, dafter = rows(states, dstates, uu)
        # diag(Jᵀ Σ J) for this chunk's columns of J (p, m): a row-wise quadratic form.
        return (after, dafter), (pred, jnp.sum(J * (cov @ J), axis=0))

    _, (pred, var) = lax.scan(body, (s0, ds0), _cov.chunked(u, u[-1], chunk))
    return pred.reshape(-1)[:T], var.reshape(-1)[:T]
