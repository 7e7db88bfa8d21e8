"""A PI model with an output offset, the model that `piest fit` writes and `load_model` reads."""

import equinox as eqx
import jax.numpy as jnp

from .._custom_types import Scalar, Signal, SignalLike, States, Thresholds, Weights
from .._operators.pi import PIOperator


class PIModel(eqx.Module):
    """A PI model y = Σ_j w_j H_{r_j}[u] + offset, in the data's units.

    What a fit leaves once its diagnostics are set aside: [`fit_pi`][]'s [`PIFit`][] holds the same
    four fields, and [`load_model`][] reads this model back from a `piest fit` JSON file.

    **Fields:**

    - `thresholds` (n,): r_1 < ... < r_n, all >= 0.
    - `weights` (n,): the plays' weights.
    - `offset` (scalar): added to the output.
    - `initial_states` (n,): the plays' states before sample 0 (a scalar is broadcast).
    """

    thresholds: Thresholds
    weights: Weights
    offset: Scalar
    initial_states: States

    def __init__(self, thresholds, weights, offset=0.0, initial_states=0.0):
        # The operator checks shapes, finiteness and threshold order with its own messages.
        op = PIOperator(thresholds, weights, initial_states)
        self.thresholds = op.thresholds
        self.weights = op.weights
        self.initial_states = op.initial_states
        self.offset = jnp.asarray(offset, op.weights.dtype)

    @property
    def n_plays(self) -> int:
        """The number of plays n."""
        return self.thresholds.shape[0]

    def operator(self) -> PIOperator:
        """The model without the offset, as a [`PIOperator`][]."""
        return PIOperator(self.thresholds, self.weights, self.initial_states)

    def __call__(self, u: SignalLike, initial_states=None) -> Signal:
        """The model output operator(u) + offset for an input `u` (T,).

        The plays start from `initial_states` (scalar or (n,)), by default the model's own.
        """
        x0 = self.initial_states if initial_states is None else initial_states
        return PIOperator(self.thresholds, self.weights, x0)(u) + self.offset
