"""A triangle wave: constant-rate sweeps between two reversals."""

from ..family import AbstractInputFamily, common
from ..signals import triangle


class Triangle(AbstractInputFamily):
    name = "triangle"
    listed = 4

    def n_uniforms(self, T):
        return 4

    def input(self, v, t, r):
        a, f, o, p = common(v, r[-1])
        return triangle(t, a, f, o, p)
