"""A square wave that touches one play's envelope exactly or sweeps it (adversarial)."""

import jax.numpy as jnp

from ..family import AbstractInputFamily
from .steps import LEVELS


class Touch(AbstractInputFamily):
    name = "touch"
    listed = 8
    adversarial = True

    def n_uniforms(self, T):
        return 2 + LEVELS

    def input(self, v, t, r):
        # Random holds between −m r_j and +m r_j, m in {1, 2, 4}: products by powers of two are
        # exact, so at m = 1 play j's other envelope is touched exactly and the play does not
        # move; at m = 2, 4 it sweeps.
        j = jnp.minimum((v[0] * r.shape[0]).astype(int), r.shape[0] - 1)
        m = jnp.asarray([1.0, 2.0, 4.0], t.dtype)[jnp.minimum((v[1] * 3).astype(int), 2)]
        # A zero threshold (the play that is u itself) gives way to r_max: the input must move.
        level = m * jnp.where(r[j] > 0, r[j], r[-1])
        span = t[-1] - t[0]
        switches = t[0] + span * jnp.sort(v[2 : 2 + LEVELS])
        flips = jnp.sum(t[:, None] >= switches, axis=1)
        return jnp.where(flips % 2 == 0, -level, level)
