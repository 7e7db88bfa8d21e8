"""The interface every hysteresis model implements: states, one step, a run, an inverse."""

import abc
from typing import Any

import equinox as eqx
import jax.numpy as jnp
from jax import lax
from jaxtyping import Array

from .. import _checks
from .._custom_types import Signal, SignalLike

State = Any


class AbstractHysteresisModel(eqx.Module):
    """A model y = M[u] of one sampled input signal, with a state carried from sample to sample.

    Subclasses provide `init_state`, `step` and `with_state`; `__call__` and `final_state` are
    scans of `step` unless a subclass has a faster form, and `inverse` and `inverse_problem` say
    there is no inverse unless it has one. Batch with `jax.vmap`. Run sample by sample:

        state = model.init_state(u[0])
        for ut in u:
            state, yt = model.step(state, ut)
    """

    @abc.abstractmethod
    def init_state(self, u0) -> State:
        """The state before the first sample: the one the model states, else at rest at `u0`."""

    @abc.abstractmethod
    def step(self, state: State, u) -> tuple[State, Any]:
        """One sample: the state after input `u` and the output there."""

    @abc.abstractmethod
    def with_state(self, state: State) -> "AbstractHysteresisModel":
        """The same model, started from `state` (as `init_state` gives or `final_state` returns)."""

    @property
    def structure(self) -> str:
        """The name model files give this kind of model."""
        return type(self).__name__

    def _signal(self, u: SignalLike) -> Array:
        return _checks.finite(_checks.signal(u, "u"), "u")

    def __call__(self, u: SignalLike, state: State | None = None) -> Signal:
        """The output (T,) for the input `u` (T,), from `state` (default `init_state(u[0])`)."""
        return run_steps(self, self._signal(u), state)

    def final_state(self, u: SignalLike, state: State | None = None) -> State:
        """The state after the last sample of `u`, to continue a run from where it ended."""
        u = self._signal(u)
        return _final(self, u, self.init_state(u[0]) if state is None else state)

    def inverse_problem(self) -> str | None:
        """Why the model has no stable inverse (one line), or None when it has one."""
        return f"a {type(self).__name__} has no inverse"

    def inverse(self, desired: SignalLike, state: State | None = None) -> Signal:
        """The input (T,) whose output follows `desired` (T,), from `state`; a `ValueError`
        where the model has no inverse."""
        raise ValueError(f"a {type(self).__name__} has no inverse")


# Compiled once per model structure and shape: an eager scan over a fresh closure compiles anew.
@eqx.filter_jit
def run_steps(model: AbstractHysteresisModel, u: SignalLike, state: State | None = None) -> Signal:
    """The output of `model` on `u` by its `step` alone (T,): what a controller stepping it gets."""
    u = jnp.asarray(u)
    if state is None:
        state = model.init_state(u[0])
    _, y = lax.scan(lambda s, ut: model.step(s, ut), state, u)
    return y


@eqx.filter_jit
def _final(model: AbstractHysteresisModel, u, state):
    last, _ = lax.scan(lambda s, ut: model.step(s, ut), state, u)
    return last
