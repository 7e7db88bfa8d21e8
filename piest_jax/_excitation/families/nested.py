"""One large cycle, then loops just too small to sweep the largest play (adversarial)."""

import jax.numpy as jnp

from ..family import AbstractInputFamily, common, log_uniform


class Nested(AbstractInputFamily):
    name = "nested"
    listed = 9
    adversarial = True

    def n_uniforms(self, T):
        return 5

    def input(self, v, t, r):
        a, f, o, _ = common(v, r[-1])
        # The large cycle over the first fifth of the record, then loops of peak-to-peak
        # 2 r_max (1 − ε), ε log-uniform in [1e-9, 1e-2].
        eps = log_uniform(v[4], 1e-9, 1e-2)
        span = t[-1] - t[0] + (t[1] - t[0])
        tt = t - t[0]
        first = tt < 0.2 * span
        big = o + a * jnp.sin(2 * jnp.pi * tt / (0.2 * span))
        loops = o + r[-1] * (1 - eps) * jnp.sin(2 * jnp.pi * f * tt)
        return jnp.where(first, big, loops)
