"""A decaying sine: large early, below 2 r_max late (Assumption 1 fails part-way)."""

import jax.numpy as jnp

from ..family import AbstractInputFamily, common


class Decaying(AbstractInputFamily):
    name = "decaying"
    listed = 5

    def n_uniforms(self, T):
        return 5

    def input(self, v, t, r):
        a, f, o, p = common(v, r[-1])
        # Decay time between 5 % and 50 % of the record.
        tau = (t[-1] - t[0] + (t[1] - t[0])) * (0.05 + 0.45 * v[4])
        return o + a * jnp.exp(-(t - t[0]) / tau) * jnp.sin(2 * jnp.pi * f * t + p)
