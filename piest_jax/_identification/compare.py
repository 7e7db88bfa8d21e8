"""Comparing a model with a measured record, as system identification does it.

A model identified on one run is judged on another by its **raw** prediction (the model run on the
new input from the initial conditions it states) and by its prediction once the new run's own
**initial conditions** are estimated (MATLAB's `compare` with estimated initial conditions): the
output offset (a sensor zero differs between runs) and the states before the first sample of the
plays and of the creep's lags (the unrecorded past). Nothing else is fitted: thresholds, weights,
time constants stay as identified, so the score measures what transfers between runs.

The play states are kept admissible, |x_{i+1} - x_i| <= r_{i+1} - r_i (states some input history
can produce), by construction: x_{i+1} = x_i + (r_{i+1} - r_i) tanh(φ_i). The offset and the lags'
states enter the output linearly, the play states piecewise linearly; all are estimated jointly by
Levenberg-Marquardt from the model's own states (the plays relaxed at u_0 when none are stated).
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from .. import _checks
from .._custom_types import Scalar, Signal
from .._models.composite import HysteresisModel
from .._models.model import AbstractHysteresisModel
from .._operators.pi import PIOperator


class Comparison(eqx.Module):
    """The result of [`compare`][].

    **Fields:**

    - `prediction` (T,): the model's output on the record.
    - `rmse`: root-mean-square error of `prediction`.
    - `fit_percent`: 100 (1 - ||e|| / ||y - mean(y)||), the sysid fit (100 is perfect, 0 is no
      better than the record's mean, negative is worse).
    - `model`: the [`HysteresisModel`][] with the initial conditions used (estimated or stated);
      for the models that saturate, judged by their raw prediction, the
      [`GeneralizedPI`][piest_jax.GeneralizedPI] or [`Preisach`][piest_jax.Preisach] model.
    """

    # A saturating model's validation (`identify`) holds a NumPy prediction and a float RMSE.
    prediction: Signal | np.ndarray
    rmse: Scalar | float
    fit_percent: Scalar
    model: AbstractHysteresisModel


def as_model(model) -> AbstractHysteresisModel:
    """`model` itself, the model a fit result holds, or a [`PIOperator`][] as a model (offset 0).
    `ValueError` for anything else."""
    if isinstance(model, PIOperator):
        return HysteresisModel(model)
    if isinstance(model, AbstractHysteresisModel):
        return model
    held = getattr(model, "model", None)
    if callable(held) and not isinstance(held, AbstractHysteresisModel):
        held = held()
    if isinstance(held, AbstractHysteresisModel):
        return held
    raise ValueError(f"`model` must be a hysteresis model or a fit holding one, got {type(model).__name__}")


def _admissible(theta, r, u0):
    d = jnp.diff(r)
    steps = d * jnp.tanh(theta["phi"])
    # A play with r_1 = 0 follows the input at once, so its own state never reaches the output,
    # and left free it would sit wherever it started and fence the others in. The states it can
    # leave behind are those admissible around x_1 = u_0.
    x1 = jnp.where(r[0] == 0, u0, theta["x1"])
    return x1 + jnp.concatenate([jnp.zeros(1, r.dtype), jnp.cumsum(steps)])


def _with_ic(model: HysteresisModel, theta, u0) -> HysteresisModel:
    x0 = _admissible(theta, model.pi.thresholds, u0)
    z0 = theta.get("z0")
    return model.with_initial_states(x0, z0, theta["offset"])


def _residuals(theta, args):
    model, u, y = args
    return (_with_ic(model, theta, u[0])(u) - y) / jnp.sqrt(u.shape[0])


@eqx.filter_jit
def _estimate(model, u, y, max_steps, rtol, atol):
    r = model.pi.thresholds
    # Start from the stated plays' states, made admissible, and the lags at rest at u_0.
    x = model.pi.initial_states
    x = x.at[0].set(jnp.where(r[0] == 0, u[0], x[0]))
    d = jnp.diff(r)
    steps = jnp.clip(jnp.diff(x), -0.999 * d, 0.999 * d)
    phi = jnp.arctanh(jnp.where(d > 0, steps / jnp.where(d > 0, d, 1.0), 0.0))
    theta = {"x1": x[0], "phi": phi, "offset": model.offset}
    if model.creep is not None:
        z = model.creep.initial_states
        theta["z0"] = jnp.broadcast_to(u[0], (model.n_lags,)) if z is None else z
    sol: optx.Solution = optx.least_squares(
        _residuals,
        optx.LevenbergMarquardt(rtol=rtol, atol=atol),
        theta,
        args=(model, u, y),
        max_steps=max_steps,
        throw=False,
    )
    loss0 = jnp.sum(_residuals(theta, (model, u, y)) ** 2)
    loss = jnp.sum(_residuals(sol.value, (model, u, y)) ** 2)
    # Keep the start when the solver made it worse (it cannot, short of a failure).
    return jax.tree.map(lambda a, b: jnp.where(loss <= loss0, a, b), sol.value, theta)


def compare(
    model, u, y=None, *, estimate_initial: bool = True, max_steps: int = 200, rtol: float = 1e-8, atol: float = 1e-10
) -> Comparison:
    """Predict a record with a model, optionally estimating the record's initial conditions.

    **Arguments:**

    - `model`: a hysteresis model (a [`HysteresisModel`][], [`GeneralizedPI`][piest_jax.GeneralizedPI]
      or [`Preisach`][piest_jax.Preisach]) or a fit holding one; initial conditions are estimated
      for a [`HysteresisModel`][] only.
    - `u`, `y`: the record's input and output (T,) each; or `u` a `Record` and `y` None.
    - `estimate_initial`: estimate the output offset and the plays' (admissible) and lags'
      initial states on this record (True), or run the model as it is (False: its stated states,
      the lags at rest at u_0 unless it states theirs).
    - `max_steps`, `rtol`, `atol`: the Levenberg-Marquardt budget and tolerances.

    **Returns:** a [`Comparison`][]. Raises `ValueError` for mismatched, empty or non-finite data.
    """
    if y is None:
        if not (hasattr(u, "u") and hasattr(u, "y")):
            raise ValueError("give `u` and `y`, or a Record as `u`")
        u, y = u.u, u.y
    if not _checks.is_whole(max_steps) or max_steps < 1:
        raise ValueError(f"`max_steps` must be a positive whole number, got {max_steps!r}")
    max_steps = int(max_steps)  # optimistix takes Python integers only
    m = as_model(model)
    u = _checks.finite(_checks.signal(u, "u"), "u")
    y = _checks.finite(_checks.signal(y, "y"), "y")
    if u.shape != y.shape:
        raise ValueError(f"`u` has {u.shape[0]} samples but `y` has {y.shape[0]}")
    dtype = jnp.result_type(u, y, *jax.tree.leaves(eqx.filter(m, eqx.is_inexact_array)))
    u, y = u.astype(dtype), y.astype(dtype)
    if estimate_initial:
        if not isinstance(m, HysteresisModel):
            raise ValueError(
                f"initial conditions are estimated for PI and PI + creep models; compare a "
                f"{type(m).__name__} with estimate_initial=False"
            )
        theta = _estimate(m, u, y, max_steps, rtol, atol)
        m = _with_ic(m, theta, u[0])
    pred = m(u)
    rmse = jnp.sqrt(jnp.mean((pred - y) ** 2))
    return Comparison(pred, rmse, fit_percent(y, pred), m)


def fit_percent(y, prediction):
    """The fit percentage system identification reports: 100 (1 − ‖y − ŷ‖ / ‖y − mean(y)‖).

    **Arguments:** `y`, the measured output (T,); `prediction`, a model's output ŷ (T,).

    **Returns:** a scalar: 100 for a perfect prediction, 0 for one no better than the record's
    mean, NaN for a constant `y`.
    """
    y, prediction = jnp.asarray(y), jnp.asarray(prediction)
    spread = jnp.linalg.norm(y - jnp.mean(y))
    return 100.0 * (1.0 - jnp.linalg.norm(y - prediction) / jnp.where(spread > 0, spread, jnp.nan))


def outside_range(u, input_range) -> np.ndarray:
    """(T,) booleans: where `u` lies outside `input_range` (min, max), its ends included inside."""
    u = np.asarray(u, float)
    lo, hi = input_range
    return (u < lo) | (u > hi)


def max_rate(t, u) -> float:
    """The fastest |du/dt| of a sampled signal (0 for one sample)."""
    u, t = np.asarray(u, np.float64), np.asarray(t, np.float64)
    return float(np.max(np.abs(np.diff(u) / np.diff(t)))) if u.size > 1 else 0.0


def extrapolation(u, identified_range, y, **predictions) -> tuple[float, dict]:
    """Where a second record's input leaves the input range a model was identified on.

    A model has seen its output only over the identification record's inputs; beyond them
    every term extrapolates (a polynomial most of all), so an error there says less about the
    model than one inside.

    **Arguments:** `u` (T,), the second record's input; `identified_range`, (min, max) of the
    identification record's input; `y` (T,), the second record's output; `predictions`, named
    predictions (T,) of it.

    **Returns:** `(outside, inside)`: the fraction of samples whose input lies outside
    `identified_range`, and for each name the prediction's RMSE over the other samples (None
    when no sample is inside).
    """
    inside = ~outside_range(u, identified_range)
    y = np.asarray(y, float)

    def rmse(prediction):
        return float(np.sqrt(np.mean((np.asarray(prediction, float) - y)[inside] ** 2))) if inside.any() else None

    return float(1.0 - inside.mean()), {name: rmse(p) for name, p in predictions.items()}
