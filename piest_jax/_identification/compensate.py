"""Feedforward hysteresis compensation with the inverse of a fitted PI model.

For a model y = P[u] + c with P a PI operator (r_1 = 0, positive cumulative weights), the input that
makes the model follow a desired output y_d is u = P⁻¹[y_d - c], with P⁻¹ the analytic inverse
([`inverse`][]). Applied to the real plant, whatever the model misses (error in the thresholds or
weights, effects outside the PI class) stays as tracking error; what the model captures is removed.

With creep (a [`HysteresisModel`][] or a fit with lags), y[t] = P[u](t) + Σ_k c_k z_k[t] + c and
z_k[t] = a_k z_k[t-1] + (1 - a_k) u[t]. The lags' part that depends on the present input,
Σ c_k (1 - a_k) u[t], is the identity play's (r_1 = 0) times a constant, so it folds into the
first weight: Q = P with w_1 + Σ c_k (1 - a_k). What remains, Σ c_k a_k z_k[t-1], is known from the
past input. So sample by sample u[t] = Q⁻¹[y_d - c - Σ c_k a_k z_k[t-1]](t), the inverse's plays
and the lags advancing in one scan: the exact inverse of PI + creep (inverse PI after the creep
compensator). It exists when Q's cumulative weights are all positive.

A generalized PI model (PI, then a saturating output function g) and a Preisach model with a
non-negative density carry their own inverses ([`GeneralizedPI.inverse`][piest_jax.GeneralizedPI.inverse]:
u = P⁻¹[g⁻¹(y_d)]; [`Preisach.inverse`][piest_jax.Preisach.inverse]: a bisection per sample);
`feedforward` calls them.

The comparison without compensation is the best linear feedforward: the straight line
u = (y_d - b)/a, where y ≈ a u + b is the least-squares line through the model's own (u, y_d) pairs,
i.e. what an engineer who ignores hysteresis but knows the gain and offset would apply.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jaxtyping import Array

from .. import _checks
from .._custom_types import Scalar, Signal, SignalLike
from .._models.composite import HysteresisModel
from .._models.creep import lag_step
from .._models.gpi import GeneralizedPI
from .._models.preisach import Preisach
from .._operators.inverse import inverse_parameters
from .._operators.pi import PIOperator, inverse
from .._operators.play import play_step
from .fit import PIFit
from .fit_gpi import GPIFit
from .fit_preisach import PreisachFit
from .pi_model import PIModel


def admissible_states(thresholds, states) -> Array:
    """The nearest states, play by play, that some input history can produce.

    Admissible states satisfy |x_{i+1} - x_i| <= r_{i+1} - r_i; each x_{i+1} is clamped into the
    band around the (already admissible) x_i. Fitted initial states need not be admissible; the
    inverse's states are only defined for admissible ones.

    **Arguments:** `thresholds` (n,), increasing; `states` (n,).

    **Returns:** (n,) admissible states, equal to `states` when they already are.
    """
    r = jnp.asarray(thresholds)
    return _admissible(r, jnp.broadcast_to(jnp.asarray(states, r.dtype), r.shape))


# One scan, not a Python loop of n dispatches (which took a minute for 20,000 plays); jitted at
# module level so that repeat calls reuse the compiled program.
@jax.jit
def _admissible(r: Array, x: Array) -> Array:
    def step(prev, xd):
        xi, d = xd
        new = jnp.clip(xi, prev - d, prev + d)
        return new, new

    _, rest = lax.scan(step, x[0], (x[1:], jnp.diff(r)))
    return jnp.concatenate([x[:1], rest])


def _check_range(c, desired) -> None:
    """Name overflow of the desired output less the offset (the inverse checks its own range)."""
    if not (_checks.is_concrete(c) and _checks.is_concrete(desired)):
        return
    with np.errstate(over="ignore", invalid="ignore"):
        v = np.asarray(desired, np.float64) - float(c)
    if not np.all(np.isfinite(v)):
        raise ValueError(
            f"the desired output less the offset {float(c):.3g} overflows float64; rescale the "
            "model's and the data's units"
        )


def _model(model, offset):
    creep = None
    if isinstance(model, PIFit):
        model = model.model()
    if isinstance(model, HysteresisModel):
        op, creep = model.pi, model.creep
        c = model.offset if offset is None else offset
    elif isinstance(model, PIModel):
        op = model.operator()
        c = model.offset if offset is None else offset
    elif isinstance(model, PIOperator):
        op, c = model, 0.0 if offset is None else offset
    else:
        raise ValueError(
            "`model` must be a PIFit, PIModel, HysteresisModel, PIOperator, GeneralizedPI or "
            f"Preisach (or their fits), got {type(model).__name__}"
        )
    return op, jnp.asarray(c, op.weights.dtype), creep


def _rest_input(op: PIOperator, gain: float, target):
    """The input u_0 at which the model at rest gives `target`: op's first output + gain·u_0.

    Used when the lags' steady gain makes the model's static map non-monotone (a creep that
    relaxes against the input more than the identity play follows it), so the closed-form
    inverse does not apply: the map is piecewise linear with corners at x_j ± r_j, every piece's
    crossing is a solution, and the one nearest the identity play's state (the last input) is
    taken. Raises `ValueError` when none reaches `target`.
    """
    r = np.asarray(op.thresholds, float)
    w = np.asarray(op.weights, float)
    x = np.asarray(op.initial_states, float)
    v = float(target)

    def f(u):
        return float(np.dot(w, np.clip(x, u - r, u + r))) + gain * u

    corners = np.unique(np.concatenate([x - r, x + r]))
    span = 1.0 + float(np.ptp(corners)) + abs(v)
    points = np.concatenate([[corners[0] - span], corners, [corners[-1] + span]])
    values = np.array([f(u) for u in points])
    slopes = np.diff(values) / np.diff(points)
    found = []
    last = len(slopes) - 1
    for i, k in enumerate(slopes):
        # The outer pieces extend without end: only their inner corner bounds them.
        if k != 0:
            u = points[i] + (v - values[i]) / k
            if (i == 0 or u >= points[i]) and (i == last or u <= points[i + 1]):
                found.append(u)
        elif values[i] == v:
            found.append(points[i])
    if not found:
        raise ValueError(
            f"the model at rest cannot reach the first desired output {v:.6g} (its creep's steady "
            "gain makes its static map non-monotone); give the lags' `creep_states`"
        )
    return min(found, key=lambda u: abs(u - x[0]))


def _creep_inverse(op: PIOperator, creep, v, creep_states=None):
    """The input u with op[u] + creep[u] = v (offset already removed), sample by sample."""
    a = creep.decays.astype(v.dtype)
    cw = creep.weights.astype(v.dtype)
    if float(op.thresholds[0]) != 0:
        raise ValueError("the model is not invertible: r_1 must be 0 (the first play the identity)")
    # The present input's share of the lags joins the identity play's weight.
    w = op.weights.at[0].add(jnp.sum(cw * (1.0 - a)))
    ri, wi, xi = inverse_parameters(op.thresholds, w, op.initial_states)
    z0 = creep_states
    if z0 is None:
        z0 = creep.initial_states
    if z0 is None:
        # At rest at the first input u_0 (as the forward model starts): then op[u](0) + Σ c u_0 =
        # v[0], so u_0 is the first sample of the inverse with the lags' whole weight folded in.
        static = op.weights.at[0].add(jnp.sum(cw))
        if _checks.is_concrete(static) and np.any(np.cumsum(np.asarray(static)) <= 0):
            z0 = _rest_input(op, float(jnp.sum(cw)), v[0])
        else:
            r0, w0, x0 = inverse_parameters(op.thresholds, static, op.initial_states)
            z0 = jnp.dot(w0, play_step(x0, v[0], r0))
        z0 = jnp.broadcast_to(z0, a.shape)

    def step(carry, vt):
        x, z = carry
        x = play_step(x, vt - jnp.dot(cw * a, z), ri)
        ut = jnp.dot(wi, x)
        return (x, lag_step(z, ut, a)), ut

    _, u = lax.scan(step, (xi, jnp.broadcast_to(jnp.asarray(z0, v.dtype), a.shape)), v)
    return u


def _own_inverse(model, desired, offset, initial_states, creep_states):
    """A generalized PI's or a Preisach model's inverse, started from `initial_states`."""
    if offset is not None or creep_states is not None:
        raise ValueError(
            f"a {type(model).__name__} has no separate offset or creep to override: "
            "give neither `offset` nor `creep_states`"
        )
    if isinstance(model, GeneralizedPI):
        if initial_states is not None:
            model = model.with_initial_states(admissible_states(model.pi.thresholds, initial_states))
        return model.inverse(desired)
    if initial_states is not None:
        model = model.with_initial_states(initial_states)
    return model.inverse(desired)


def feedforward(
    model: PIFit | PIModel | HysteresisModel | PIOperator | GeneralizedPI | Preisach,
    desired: SignalLike,
    *,
    offset=None,
    initial_states=None,
    creep_states=None,
) -> Signal:
    """The input that makes the model's output follow `desired`: u = P⁻¹[desired - offset], or
    with creep the sample-by-sample inverse of PI + creep described above.

    **Arguments:**

    - `model`: a [`PIFit`][], [`PIModel`][] or [`HysteresisModel`][] (its offset, and creep when
      it has one, are used) or a [`PIOperator`][] (offset 0 unless given); or a
      [`GeneralizedPI`][piest_jax.GeneralizedPI] or [`Preisach`][piest_jax.Preisach] (or the fit
      holding one), inverted by its own `inverse` (no `offset` or `creep_states` then).
    - `desired`: the desired output trajectory (T,).
    - `offset`: overrides the model's output offset.
    - `initial_states`: the plant's play states at the start (scalar or (n,)); default the model's,
      made admissible with [`admissible_states`][] (a Preisach model's are taken as given; by
      default it starts at rest at the first input).
    - `creep_states`: the lags' states at the start (scalar or (K,)); default the model's, or at
      rest at the input that the plays' states give for the first target.

    **Returns:** the feedforward input (T,). Raises `ValueError` when the model is not invertible
    (r_1 != 0 or a cumulative weight <= 0, the creep's share of the first weight included; fit
    with `positive_weights=True` to keep the plays' part invertible), when a generalized PI's
    desired output leaves the range it saturates at, or when a Preisach density is negative.
    """
    if isinstance(model, GPIFit | PreisachFit):
        model = model.model
    if isinstance(model, GeneralizedPI | Preisach):
        return _own_inverse(model, desired, offset, initial_states, creep_states)
    op, c, creep = _model(model, offset)
    yd = _checks.finite(_checks.signal(desired, "desired"), "desired")
    x0 = op.initial_states if initial_states is None else initial_states
    x0 = admissible_states(op.thresholds, x0)
    op = PIOperator(op.thresholds, op.weights, x0, method=op.method)
    _check_range(c, yd)
    if creep is not None:
        return _creep_inverse(op, creep, yd - c, creep_states)
    return inverse(op)(yd - c)


class Compensation(eqx.Module):
    """Tracking with and without compensation, from [`evaluate_compensation`][].

    **Fields:** `desired`; `u_compensated`, `y_compensated` (the inverse-model feedforward and the
    plant's response); `u_linear`, `y_linear` (the best linear feedforward and the response);
    `rmse_compensated`, `rmse_linear` (tracking RMSE of each).
    """

    desired: Signal
    u_compensated: Signal
    y_compensated: Signal
    u_linear: Signal
    y_linear: Signal
    rmse_compensated: Scalar
    rmse_linear: Scalar


def linear_feedforward(u_ff: SignalLike, desired: SignalLike) -> Signal:
    """The best straight-line feedforward: u = (desired - b)/a with desired ≈ a u_ff + b (LS).

    **Arguments:** `u_ff`, an input that produces `desired` (e.g. from [`feedforward`][]); `desired`.

    **Returns:** the linear feedforward input (T,).
    """
    u = _checks.signal(u_ff, "u_ff")
    yd = _checks.signal(desired, "desired")
    A = jnp.stack([u, jnp.ones_like(u)], axis=1)
    a, b = jnp.linalg.lstsq(A, yd)[0]
    return (yd - b) / a


def evaluate_compensation(plant, model, desired: SignalLike, **feedforward_kwargs) -> Compensation:
    """Drive `plant` with the inverse-model feedforward and with the linear one; compare tracking.

    **Arguments:**

    - `plant`: a callable u (T,) -> y (T,), e.g. a [`PIOperator`][] plus effects the model lacks.
    - `model`, `desired`, `feedforward_kwargs`: as for [`feedforward`][].

    **Returns:** a [`Compensation`][].
    """
    yd = _checks.signal(desired, "desired")
    u_c = feedforward(model, yd, **feedforward_kwargs)
    u_l = linear_feedforward(u_c, yd)
    y_c, y_l = jnp.asarray(plant(u_c)), jnp.asarray(plant(u_l))
    if y_c.shape != yd.shape:
        raise ValueError(f"`plant` returned shape {y_c.shape} for an input of shape {yd.shape}")
    rms = lambda e: jnp.sqrt(jnp.mean(e**2))  # noqa: E731
    return Compensation(yd, u_c, y_c, u_l, y_l, rms(y_c - yd), rms(y_l - yd))
