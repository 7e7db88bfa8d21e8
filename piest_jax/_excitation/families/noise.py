"""Band-limited noise: a random-phase multisine with a flat spectrum up to a cut-off."""

import jax.numpy as jnp

from ..family import AbstractInputFamily, common


class Noise(AbstractInputFamily):
    name = "noise"
    listed = 2

    def n_uniforms(self, T):
        return 5 + T // 2

    def input(self, v, t, r):
        a, f, o, _ = common(v, r[-1])
        # A flat spectrum up to a cut-off of 2f with independent uniform phases, centred and
        # scaled so that its largest excursion is a.
        T = t.shape[0]
        dt = t[1] - t[0]
        phases = 2 * jnp.pi * v[4 : 4 + T // 2 + 1]
        spectrum = jnp.where(jnp.fft.rfftfreq(T, dt) <= 2.0 * f, jnp.exp(1j * phases), 0.0)
        x = jnp.fft.irfft(spectrum.at[0].set(0.0), n=T)
        return o + a * x / jnp.maximum(jnp.max(jnp.abs(x)), jnp.finfo(t.dtype).tiny)
