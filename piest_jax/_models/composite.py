"""The composite model y = PI[u] + C[u] + offset: a PI operator, an optional creep, an offset.

One definition used by fitting, validation, compensation and the Python API. The PI part is a
[`PIOperator`][] (the one play recurrence of the operators) and the creep part a [`Creep`][] bank
of first-order lags of the input; without creep the model is the plain PI model.
"""

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .. import _checks
from .._custom_types import Scalar, Signal, SignalLike
from .._operators.pi import PIOperator
from .creep import Creep


class HysteresisModel(eqx.Module):
    """y = Σ_j w_j H_{r_j}[u] + Σ_k c_k z_k[u] + offset, sampled every `dt`.

    **Arguments:**

    - `pi`: a [`PIOperator`][] (thresholds, weights, the plays' initial states).
    - `creep`: a [`Creep`][] with the same `dt`, or None for a plain PI model.
    - `offset`: the output offset.
    - `dt`: the sampling interval; taken from `creep` when None.

    `__call__` takes one input signal (T,) sampled every `dt`; batch with `jax.vmap`.
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

    def __call__(self, u: SignalLike) -> Signal:
        """The model output (T,) for the input `u` (T,)."""
        y = self.pi(u) + self.offset
        if self.creep is not None:
            y = y + self.creep(u)
        return y

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
