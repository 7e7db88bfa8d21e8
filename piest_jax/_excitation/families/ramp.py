"""A slow triangle: monotone stretches longer than a window (adversarial)."""

from ..family import AbstractInputFamily, common
from ..signals import triangle


class Ramp(AbstractInputFamily):
    name = "ramp"
    listed = 7
    adversarial = True

    def n_uniforms(self, T):
        return 4

    def input(self, v, t, r):
        a, f, o, p = common(v, r[-1])
        # Ten times slower than the triangle family: stretches of range up to 8 r_max.
        return triangle(t, a, f / 10, o, p)
