"""Creep: after a change the output keeps moving slowly the same way (slow modes of the output)."""

import jax
import jax.numpy as jnp
import numpy as np

from ..._identification.fit import _softplus_inv
from ..._models.creep import lag_states
from .. import synthetic
from ..effect import AbstractEffect

N_CREEP = 5  # creep modes, log-spaced from a third of the input's period to the record's length


# Compiled once per shape: the search calls it thousands of times on NumPy arrays, where each
# eager call would trace the scan again (a third of a search's time, for the same numbers).
@jax.jit
def lowpass(v, lam):
    """First-order low-pass y_t = lam y_t-1 + (1 - lam) v_t from rest at v_0, `lam` (k,) -> (T, k).

    The creep operator's lag recurrence ([`piest_jax.Creep`][]), so the diagnosis and the fitted
    model share one definition; traceable in `v` and `lam`.
    """
    v = jnp.asarray(v)
    lam = jnp.asarray(lam, v.dtype)
    return lag_states(v, lam, jnp.full(lam.shape, v[0]), method="scan")


class Creep(AbstractEffect):
    """y = v + sum_k c_k (lowpass_tau_k(drive) - drive), c_k >= 0, q = the time constants (s).

    The drive is the output before creep (after the output map): creep is a slow yield of
    the displacement itself. A positive coefficient is an output that keeps moving after a
    change, in the direction of the change.
    """

    name = "creep"
    summary = "after a change the output keeps moving slowly the same way"
    rank = 6
    listed = 4
    n_params = N_CREEP
    positive = True
    fit_iterations = 2

    def grid(self, p):
        duration = p.t[-1] - p.t[0]
        return [tuple(np.geomspace(min(0.1 * p.period, duration / 10), duration, N_CREEP))]

    def describe(self, q):
        return {"time_constants_s": [float(v) for v in q]}

    def n_columns(self, q):
        return len(q)

    def columns(self, q, p, v, drive, norm):
        lp = np.asarray(lowpass(drive, np.exp(-p.dt / np.asarray(q))))
        return lp - drive[:, None]

    def transients(self, q, p):
        # A mode starting away from rest adds lam^(t+1) times its initial offset.
        lam = np.exp(-p.dt / np.asarray(q, float))
        return lam[None, :] ** (np.arange(len(p.u))[:, None] + 1)

    def static(self, q):
        return len(q)

    def init_theta(self, q, coef):
        # A coefficient at exactly 0 would sit where the softplus is flat and never move.
        c = np.maximum(coef, 1e-3 * max(float(np.max(np.abs(coef))), 1e-12))
        return {"creep": _softplus_inv(c), "log_creep_tau": np.log(np.asarray(q, float))}

    def from_theta(self, q, theta):
        taus = tuple(float(v) for v in np.exp(theta["log_creep_tau"]))
        return taus, [np.asarray(jax.nn.softplus(theta["creep"]), float)]

    def jax_output(self, theta, static, y, v, data):
        # Driven by the output so far (after the output map), as in `columns`.
        lam = jnp.exp(-data["dt"] / jnp.exp(theta["log_creep_tau"]))
        c = jax.nn.softplus(theta["creep"])
        return y + (lowpass(y, lam) - y[:, None]) @ c

    def draw(self, prng, ctx):
        c = prng.uniform(0.08, 0.2)
        taus = ctx.t[-1] * np.array([prng.uniform(0.01, 0.04), prng.uniform(0.1, 0.4)])
        t0 = prng.uniform(0.2, 1.0) / max(ctx.f0, 1e-9) / 10
        if prng.random() < 0.5:
            return {"form": "two slow exponential modes", "c": c, "taus": taus}
        return {"form": "logarithmic, log(1 + t/t0)", "c": c, "t0": t0}

    def synth_output(self, state, ctx, v, y):
        c = state["c"]
        if "taus" in state:
            return v, y + c * sum(synthetic.lowpass(v, np.exp(-ctx.dt / tau)) - v for tau in state["taus"]) * 0.5
        # Logarithmic creep: every output change keeps growing as log(1 + t/t0).
        kern = np.log1p(np.arange(len(ctx.t)) * ctx.dt / state["t0"])
        kern = kern / kern[-1]
        return v, y + c * 1.5 * np.convolve(np.diff(v, prepend=v[0]), kern)[: len(ctx.t)]
