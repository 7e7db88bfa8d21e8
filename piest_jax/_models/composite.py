"""The composite model y = PI[u] + C[u] + offset: a PI operator, an optional creep, an offset.

One definition used by fitting, validation, compensation, model files and the Python API. The PI
part is a [`PIOperator`][] (the one play recurrence of the operators) and the creep part a
[`Creep`][] bank of first-order lags of the input; without creep the model is the plain PI model.
"""

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .. import _checks
from .._custom_types import Scalar, Signal, SignalLike
from .._operators.inverse import inverse_problem
from .._operators.pi import PIOperator
from .._operators.play import play_step
from .composite_inverse import creep_inverse
from .creep import Creep, lag_step
from .model import AbstractHysteresisModel


class HysteresisModel(AbstractHysteresisModel):
    """y = Σ_j w_j H_{r_j}[u] + Σ_k c_k z_k[u] + offset, sampled every `dt`.

    **Arguments:**

    - `pi`: a [`PIOperator`][] (thresholds, weights, the plays' initial states).
    - `creep`: a [`Creep`][] with the same `dt`, or None for a plain PI model.
    - `offset`: the output offset.
    - `dt`: the sampling interval; taken from `creep` when None.

    `__call__` takes one input signal (T,) sampled every `dt`; batch with `jax.vmap`. The state
    is `(play_states, lag_states)` (`lag_states` None without creep).
    """

    pi: PIOperator
    creep: Creep | None
    offset: Scalar
    dt: float = eqx.field(static=True)

    def __init__(self, pi: PIOperator, creep: Creep | None = None, offset=0.0, dt=None):
        if not isinstance(pi, PIOperator):
            raise ValueError(f"`pi` must be a PIOperator, got {type(pi).__name__}")
        if creep is not None and not isinstance(creep, Creep):
            raise ValueError(f"`creep` must be a Creep or None, got {type(creep).__name__}")
        if dt is None:
            dt = 1.0 if creep is None else creep.dt
        if not (np.isfinite(dt) and dt > 0):
            raise ValueError(f"`dt` must be a positive finite number, got {dt!r}")
        if creep is not None and not np.isclose(creep.dt, dt, rtol=1e-9, atol=0):
            raise ValueError(f"`creep.dt` = {creep.dt} differs from the model's dt = {dt}")
        self.pi = pi
        self.creep = creep
        self.offset = _checks.finite(jnp.asarray(offset, pi.weights.dtype), "offset")
        self.dt = float(dt)

    @property
    def structure(self) -> str:
        """`"pi"` or `"pi+creep"`."""
        return "pi" if self.creep is None else "pi+creep"

    @property
    def n_lags(self) -> int:
        """The number of creep lags (0 without creep)."""
        return 0 if self.creep is None else self.creep.n_lags

    def init_state(self, u0):
        """`(play_states, lag_states)`: the model's own, the lags at rest at `u0` unless stated."""
        z = None
        if self.creep is not None:
            z = self.creep.initial_states
            if z is None:
                z = jnp.broadcast_to(jnp.asarray(u0, self.creep.weights.dtype), self.creep.weights.shape)
        return self.pi.initial_states, z

    def step(self, state, u):
        """One sample: `((play_states, lag_states), y)` after the input `u`."""
        x, z = state
        x = play_step(x, u, self.pi.thresholds)
        y = jnp.dot(self.pi.weights, x) + self.offset
        if self.creep is not None:
            z = lag_step(z, u, self.creep.decays)
            y = y + jnp.dot(self.creep.weights, z)
        return (x, z), y

    def with_state(self, state) -> "HysteresisModel":
        """The same model started from `(play_states, lag_states)`."""
        x, z = state
        return self.with_initial_states(x, z)

    def __call__(self, u: SignalLike, state=None) -> Signal:
        """The model output (T,) for the input `u` (T,), from `state` (default the model's own)."""
        m = self if state is None else self.with_state(state)
        y = m.pi(u) + m.offset
        if m.creep is not None:
            y = y + m.creep(u)
        return y

    def final_state(self, u: SignalLike, state=None):
        """`(play_states, lag_states)` after the last sample of `u`."""
        m = self if state is None else self.with_state(state)
        return m.pi.final_states(u), None if m.creep is None else m.creep.final_states(u)

    def inverse_problem(self) -> str | None:
        """Why the model has no stable inverse, or None: the PI operator with the lags' share of
        the present input added to its first weight must be invertible (`inverse_problem` of the
        operators), and, for an inverse that does not drift, so must the one with the lags' steady
        gain added."""
        w = np.asarray(self.pi.weights, np.float64)
        c = a = np.zeros(0)
        if self.creep is not None:
            c = np.asarray(self.creep.weights, np.float64)
            a = np.asarray(self.creep.decays, np.float64)
        first = np.eye(w.size)[0]
        problem = inverse_problem(self.pi.thresholds, w + first * np.sum(c * (1 - a)))
        if problem is None and inverse_problem(self.pi.thresholds, w + first * np.sum(c)) is not None:
            problem = (
                f"the creep's steady gain ({np.sum(c):.4g}) outweighs the first play's weight ({w[0]:.4g}), "
                "so the static map falls where only that play moves and the feedforward drifts on "
                "slow targets"
            )
        return problem

    def inverse(self, desired: SignalLike, state=None) -> Signal:
        """The input (T,) whose output follows `desired` (T,), from `state` (default the model's
        own; the lags at rest at the input the first target needs unless stated).

        Exact for PI + creep (module `composite_inverse`). `ValueError` when the model is not
        invertible: r_1 != 0, or a cumulative weight <= 0 (the lags' share of the present input
        counted with the first), or play states no input history can produce.
        """
        yd = _checks.finite(_checks.signal(desired, "desired"), "desired")
        m = self if state is None else self.with_state(state)
        if _checks.is_concrete(m.offset) and _checks.is_concrete(yd):
            with np.errstate(over="ignore", invalid="ignore"):
                finite = np.all(np.isfinite(np.asarray(yd, np.float64) - float(m.offset)))
            if not finite:
                raise ValueError(
                    f"the desired output less the offset {float(m.offset):.3g} overflows float64; rescale the "
                    "model's and the data's units"
                )
        v = yd - m.offset
        if m.creep is None:
            return m.pi.inverse()(v)
        return creep_inverse(m.pi, m.creep, v)

    def with_initial_states(self, play_states=None, creep_states=None, offset=None):
        """The same model started from other states (or with another offset).

        **Arguments:** `play_states` (n,) or scalar, `creep_states` (K,) or scalar, `offset`; None
        keeps the model's own (for the creep: at rest at the first input unless stated).

        **Returns:** a new `HysteresisModel`.
        """
        pi, creep = self.pi, self.creep
        if play_states is not None:
            pi = PIOperator(pi.thresholds, pi.weights, play_states, method=pi.method)
        if creep is not None and creep_states is not None:
            creep = Creep(creep.time_constants, creep.weights, creep.dt, creep_states, method=creep.method)
        return HysteresisModel(pi, creep, self.offset if offset is None else offset, self.dt)
