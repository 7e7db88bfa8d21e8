"""Feedforward hysteresis compensation with the inverse of a fitted model.

The input that makes a model follow a desired output y_d is the model's own inverse: u =
P⁻¹[y_d - c] for a PI model, sample by sample for PI + creep (`_models/composite_inverse.py`), u =
P⁻¹[g⁻¹(y_d)] for a generalized PI and a bisection per sample for a Preisach model;
`feedforward` calls it. Applied to the real plant, whatever the model misses stays as tracking
error; what the model captures is removed.

The comparison without compensation is the best linear feedforward: the straight line
u = (y_d - b)/a, where y ≈ a u + b is the least-squares line through the model's own (u, y_d) pairs,
i.e. what an engineer who ignores hysteresis but knows the gain and offset would apply.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
from jax import lax
from jaxtyping import Array

from .. import _checks
from .._custom_types import Scalar, Signal, SignalLike
from .._models.composite import HysteresisModel
from .._models.model import AbstractHysteresisModel
from .._models.preisach import Preisach
from .._operators.pi import PIOperator
from .compare import as_model
from .fit import PIFit
from .fit_gpi import GPIFit
from .fit_preisach import PreisachFit


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


def _as_model(model, offset) -> AbstractHysteresisModel:
    """The model to invert (`as_model`), with `offset` if given."""
    model = as_model(model)
    if offset is not None:
        if not isinstance(model, HysteresisModel):
            raise ValueError(
                f"a {type(model).__name__} has no separate offset or creep to override: "
                "give neither `offset` nor `creep_states`"
            )
        model = model.with_initial_states(offset=offset)
    return model


def feedforward(
    model: AbstractHysteresisModel | PIFit | GPIFit | PreisachFit | PIOperator,
    desired: SignalLike,
    *,
    offset=None,
    initial_states=None,
    creep_states=None,
) -> Signal:
    """The input that makes the model's output follow `desired`: the model's `inverse`.

    **Arguments:**

    - `model`: a hysteresis model ([`HysteresisModel`][], [`GeneralizedPI`][piest_jax.GeneralizedPI],
      [`Preisach`][piest_jax.Preisach]), a fit holding one, or a [`PIOperator`][] (offset 0).
    - `desired`: the desired output trajectory (T,).
    - `offset`: overrides a [`HysteresisModel`][]'s output offset.
    - `initial_states`: the plant's play states at the start (scalar or (n,)); default the model's,
      made admissible with [`admissible_states`][] (a Preisach model's are taken as given; by
      default it starts at rest at the first input).
    - `creep_states`: the lags' states at the start (scalar or (K,)); default the model's, or at
      rest at the input that the plays' states give for the first target.

    **Returns:** the feedforward input (T,). Raises `ValueError` when the model is not invertible
    (r_1 != 0 or a cumulative weight <= 0, the creep's share of the first weight included), when a
    generalized PI's desired output leaves the range it saturates at, or when a Preisach density
    is negative.
    """
    return started(model, initial_states, creep_states, offset=offset).inverse(desired)


def started(model, initial_states=None, creep_states=None, *, offset=None) -> AbstractHysteresisModel:
    """The model `feedforward` inverts: `model` (or the one a fit holds) started from the plays'
    `initial_states` made admissible (a Preisach model's as given) and the lags' `creep_states`,
    with `offset` if given; None keeps the model's own (a [`HysteresisModel`][]'s play states are
    made admissible all the same)."""
    m = _as_model(model, offset)
    if creep_states is not None and not (isinstance(m, HysteresisModel) and m.creep is not None):
        raise ValueError(f"a {type(m).__name__} without creep has no lags whose `creep_states` could be set")
    if isinstance(m, HysteresisModel):
        x0 = m.pi.initial_states if initial_states is None else initial_states
        return m.with_initial_states(admissible_states(m.pi.thresholds, x0), creep_states)
    if initial_states is None:
        return m
    if isinstance(m, Preisach):
        # A Preisach model's plays share no band constraint: any states are theirs.
        return m.with_initial_states(initial_states)
    # A generalized PI: its PI part's states.
    return m.with_state(admissible_states(getattr(m, "pi").thresholds, initial_states))


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
