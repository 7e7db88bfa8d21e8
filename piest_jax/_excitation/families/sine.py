"""A sine of random amplitude, frequency, offset and phase."""

import jax.numpy as jnp

from ..family import AbstractInputFamily, common


class Sine(AbstractInputFamily):
    name = "sine"
    listed = 0

    def n_uniforms(self, T):
        return 4

    def input(self, v, t, r):
        a, f, o, p = common(v, r[-1])
        return o + a * jnp.sin(2 * jnp.pi * f * t + p)
