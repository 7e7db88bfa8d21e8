"""Initial state: the plays start where an unrecorded input history left them, not relaxed."""

import jax.numpy as jnp
import numpy as np

from ..._operators.play import _bank
from ..basis import THRESHOLDS, history_states, plays
from ..effect import AbstractEffect


class InitialState(AbstractEffect):
    """The plays' states before the first sample, as an input history u0 -> turns -> u0 leaves them.

    A history keeps the states reachable (a PI model cannot start anywhere else), and a few
    turning points describe any state the record needs. Tied to the record: the next run has
    another past.
    """

    name = "initial_state"
    summary = "plays start where an unrecorded input history left them"
    rank = 0
    listed = 0
    n_params = 2
    record_specific = True
    play_side = True

    def grid(self, p):
        u0 = p.u[0]
        one = [(u0 + a,) for a in np.linspace(-2.5, 2.5, 41) if abs(a) > 1e-9]
        lv = np.linspace(-2.5, 2.5, 11)
        two = [(u0 + a, u0 + b) for a in lv for b in lv if a * b < 0 and abs(b) < abs(a)]
        seen, out = set(), []
        for turns in one + two:
            key = tuple(np.round(history_states(u0, turns), 9))
            if key not in seen and np.any(np.abs(np.array(key) - u0) > 1e-9):
                seen.add(key)
                out.append(turns)
        return out

    def describe(self, q):
        return {"history_turning_points_normalised_input": [float(a) for a in q]}

    def initial_states(self, q, g0, x0):
        return history_states(g0, q)

    def batch_play_columns(self, p, g, r, values):
        # All histories at once: one pass of the plays with a batch of initial states.
        return plays(g, r, np.stack([history_states(g[0], tr) for tr in values]), p.keep)

    def static(self, q):
        return len(q)

    def init_theta(self, q, coef):
        return {"turns": np.asarray(q, float)}

    def from_theta(self, q, theta):
        return tuple(float(v) for v in theta["turns"]), []

    def jax_initial_states(self, theta, static, g0, x0):
        # The history u0 -> turns -> u0 run through the play operator from relaxed states at u0,
        # without `play`'s checks of traced values, as in `refine._hysteresis` (there: why).
        r = jnp.asarray(THRESHOLDS, g0.dtype)
        history = jnp.append(jnp.asarray(theta["turns"], g0.dtype), g0)
        return _bank(history, r, jnp.full(r.shape, g0), "scan")[-1]

    def draw(self, prng, ctx):
        # Memory of an earlier excursion beyond what this record reaches first.
        top = prng.choice([-1, 1]) * ctx.amp * prng.uniform(0.9, 1.3)
        pre = np.concatenate([np.linspace(0, top, 50), np.linspace(top, 0, 50)])
        return {"form": "states left by an earlier excursion", "pre": pre}

    def synth_input(self, state, ctx, chain):
        chain.x0 = plays(state["pre"], ctx.r, np.zeros((1, len(ctx.r))))[0, -1]
