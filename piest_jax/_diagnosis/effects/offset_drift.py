"""Offset drift: the output's zero wanders over the record (warm-up, a slow disturbance)."""

import jax.numpy as jnp
import numpy as np

from ..effect import AbstractEffect

N_DRIFT = 6


class OffsetDrift(AbstractEffect):
    """y = v + sum_k d_k cos(k pi s), s = t / duration: a smooth drift over the record's time axis.

    A function of time, tied to the record: it cannot carry over to another run.
    """

    name = "offset_drift"
    summary = "the output's zero wanders along the record's time axis"
    rank = 7
    listed = 6
    n_params = N_DRIFT
    record_specific = True
    time_driven = True

    def n_columns(self, q):
        return N_DRIFT

    def columns(self, q, p, v, drive, norm):
        return np.column_stack([np.cos(k * np.pi * p.s) for k in range(1, N_DRIFT + 1)])

    def init_theta(self, q, coef):
        return {"drift": coef}

    def from_theta(self, q, theta):
        return q, [theta["drift"]]

    def jax_output(self, theta, static, y, v, data):
        k = jnp.arange(1, N_DRIFT + 1)
        return y + jnp.cos(jnp.pi * data["s"][:, None] * k[None, :]) @ theta["drift"]

    def draw(self, prng, ctx):
        d = prng.uniform(0.04, 0.1) * ctx.span0
        kind = str(prng.choice(["ramp", "warm-up", "oscillation"]))
        s = ctx.t / ctx.t[-1]
        shape = {
            "ramp": s,
            "warm-up": 1 - np.exp(-s / prng.uniform(0.1, 0.3)),
            "oscillation": np.sin(2 * np.pi * s * prng.uniform(0.5, 1.5) + prng.uniform(0, 6)),
        }[kind]
        return {"form": kind, "drift": d * shape * prng.choice([-1, 1])}

    def synth_output(self, state, ctx, v, y):
        return v, y + state["drift"]
