"""Three sines whose amplitudes add up to the drawn amplitude."""

import jax.numpy as jnp

from ..family import AbstractInputFamily, common, log_uniform


class Multisine(AbstractInputFamily):
    name = "multisine"
    listed = 1

    def n_uniforms(self, T):
        return 13

    def input(self, v, t, r):
        a, f, o, _ = common(v, r[-1])
        # The amplitudes add up to a, so the peak never exceeds o ± a. Normalised unit
        # exponentials are a uniform draw on the simplex (a flat Dirichlet).
        e = -jnp.log1p(-v[4:7])
        share = e / jnp.sum(e)
        freqs = f * log_uniform(v[7:10], 1.0, 6.0).at[0].set(1.0)
        phases = 2 * jnp.pi * v[10:13]
        return o + jnp.sum(a * share * jnp.sin(2 * jnp.pi * freqs * t[:, None] + phases), axis=1)
