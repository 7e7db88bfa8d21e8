"""A triangle wave: constant-rate sweeps between two reversals."""

from ..signals import triangle
from .family import AbstractInputFamily, common


class Triangle(AbstractInputFamily):
    name = "triangle"

    def n_uniforms(self, T):
        return 4

    def input(self, v, t, r):
        a, f, o, p = common(v, r[-1])
        return triangle(t, a, f, o, p)
