"""A linear chirp from the drawn frequency to a fifth to five times it."""

from ..family import AbstractInputFamily, common, log_uniform
from ..signals import chirp


class Chirp(AbstractInputFamily):
    name = "chirp"
    listed = 3

    def n_uniforms(self, T):
        return 5

    def input(self, v, t, r):
        a, f, o, _ = common(v, r[-1])
        return chirp(t, a, f, f * log_uniform(v[4], 0.2, 5.0), o)
