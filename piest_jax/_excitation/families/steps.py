"""Random steps: levels held for random times, each switch a jump within one sample."""

import jax.numpy as jnp

from ..family import AbstractInputFamily, common

LEVELS = 12


class Steps(AbstractInputFamily):
    name = "steps"
    listed = 6

    def n_uniforms(self, T):
        return 3 + 2 * LEVELS

    def input(self, v, t, r):
        a, _, o, _ = common(v, r[-1])
        levels = o + a * (2 * v[4 : 4 + LEVELS] - 1)
        # Sorted switching instants over the record. Each switch is a jump within one sample, so
        # the input is not continuous (outside the hypotheses of the paper's Theorem 1).
        span = t[-1] - t[0]
        switches = t[0] + span * jnp.sort(v[4 + LEVELS : 3 + 2 * LEVELS])
        return levels[jnp.sum(t[:, None] >= switches, axis=1)]
