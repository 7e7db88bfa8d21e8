"""Delay: the output follows the input a fixed time late (transport, sensor or driver latency)."""

import jax.numpy as jnp
import numpy as np

from ..effect import AbstractEffect, refinement_factor


def delayed(X, d):
    """Columns of X delayed by d samples (fractional, linear interpolation; the start is held)."""
    if d <= 0:
        return X
    k, f = int(np.floor(d)), d - np.floor(d)
    idx = np.arange(len(X))
    a = X[np.clip(idx - k, 0, None)]
    b = X[np.clip(idx - k - 1, 0, None)]
    return (1 - f) * a + f * b


def delayed_jax(v, d):
    """v delayed by d >= 0 samples, as `delayed` (traceable in d)."""
    k = jnp.floor(d)
    f = d - k
    idx = jnp.arange(v.shape[0])
    a = v[jnp.clip(idx - k.astype(idx.dtype), 0, None)]
    b = v[jnp.clip(idx - k.astype(idx.dtype) - 1, 0, None)]
    return (1 - f) * a + f * b


# The record length at which the generator's delays are drawn in samples (`Delay.draw`).
DRAW_SAMPLES = 500


class Delay(AbstractEffect):
    """A pure delay of d seconds, fractional, applied to the play columns: X(t - d)."""

    name = "delay"
    summary = "the output lags the input by a fixed time"
    rank = 1
    listed = 1
    n_params = 1

    def grid(self, p):
        top = max(64.0, 0.1 * p.period / p.dt)
        return list(np.geomspace(0.25, top, 36) * p.dt)

    def neighbours(self, q, level):
        f = refinement_factor(level)
        return [q / f, q * f]

    def describe(self, q):
        return {"delay_s": float(q)}

    def linear(self, q, X, dt):
        return delayed(X, q / dt)

    def init_theta(self, q, coef):
        return {"log_delay": np.log(np.asarray(float(q)))}

    def from_theta(self, q, theta):
        return float(np.exp(theta["log_delay"])), []

    def jax_linear(self, theta, static, v, data):
        return delayed_jax(v, jnp.exp(theta["log_delay"]) / data["dt"])

    def draw(self, prng, ctx):
        # 1.5 to 8 samples of a 500-sample record, the same fraction of the input's cycle (2 to
        # 20 %) at any length: a delay of a fixed number of samples would shrink against the
        # cycle as records grow, below what any length's naming bar is meant to find.
        d = prng.uniform(1.5, 8.0) * ctx.dt * (len(ctx.t) / DRAW_SAMPLES)
        return {"form": f"input delayed by {d / ctx.dt:.2f} samples", "d": d}

    def synth_input(self, state, ctx, chain):
        chain.u = np.interp(ctx.t - state["d"], ctx.t, ctx.u, left=ctx.u[0])
