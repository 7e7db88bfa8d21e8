"""Rate dependence: loops widen with the input's rate, thresholds that grow with |du/dt|."""

import jax.numpy as jnp
import numpy as np

from ..effect import AbstractEffect, refinement_factor


def rate_power(rho, exponent):
    """rho^p, traceable in p, with rho = 0 allowed (the power's gradient rho^p log rho is 0 there)."""
    pos = rho > 0
    safe = jnp.where(pos, rho, 1.0)
    return jnp.where(pos, jnp.exp(exponent * jnp.log(safe)), 0.0)


class RateDependence(AbstractEffect):
    """Thresholds r_j (1 + k rho^p) ("scale") or r_j + k rho^p ("add"), rho the normalised rate.

    The plays run with thresholds that vary over time; the grid value is (form, k, p).
    """

    name = "rate_dependence"
    summary = "loops widen with the input's rate (thresholds grow with |du/dt|)"
    rank = 2
    listed = 3
    n_params = 2
    play_side = True

    def grid(self, p):
        return [("scale", k, e) for k in (0.1, 0.25, 0.5, 1.0, 2.0, 4.0) for e in (0.5, 1.0)] + [
            ("add", k, e) for k in (0.01, 0.025, 0.05, 0.1, 0.2, 0.4) for e in (0.5, 1.0)
        ]

    def neighbours(self, q, level):
        f = refinement_factor(level)
        return [(q[0], q[1] / f**2, q[2]), (q[0], q[1] * f**2, q[2])]

    def describe(self, q):
        return {"form": "r (1 + k rho^p)" if q[0] == "scale" else "r + k rho^p", "k": q[1], "p": q[2]}

    def thresholds(self, q, p, r):
        form, k, e = q
        rp = p.play_rho[:, None] ** e
        return r[None, :] * (1 + k * rp) if form == "scale" else r[None, :] + k * rp

    def static(self, q):
        return q[0]

    def init_theta(self, q, coef):
        return {"log_rate": np.log(np.asarray(q[1:], float))}

    def from_theta(self, q, theta):
        gain, exponent = np.exp(theta["log_rate"])
        return (q[0], float(gain), float(exponent)), []

    def jax_thresholds(self, theta, static, r, r0, rho):
        gain, exponent = jnp.exp(theta["log_rate"][0]), jnp.exp(theta["log_rate"][1])
        rp = rate_power(rho, exponent)[:, None]
        return r0[None, :] * (1 + gain * rp) if static == "scale" else r0[None, :] + gain * rp

    def draw(self, prng, ctx):
        rate = np.abs(np.gradient(ctx.u, ctx.t))
        rate = rate / np.percentile(rate, 95)
        b = prng.uniform(0.5, 1.2)
        if prng.random() < 0.5:
            return {"form": "thresholds proportional to 1 + b|du/dt|", "rt": ctx.r[None, :] * (1 + b * rate[:, None])}
        return {
            "form": "thresholds grow with sqrt|du/dt|",
            "rt": ctx.r[None, :] + b * 0.15 * ctx.amp * np.sqrt(rate)[:, None],
        }

    def synth_input(self, state, ctx, chain):
        chain.rt = state["rt"]
