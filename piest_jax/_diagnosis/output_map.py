"""The memoryless output map that the asymmetry (even part) and saturation (odd part) effects share.

A memoryless output map y = f(v) around the centre of the loop splits into an even part, which
makes the loop lose its point symmetry, and an odd part, which keeps it and bends both ends alike.
Each effect fits its own part as columns of the centred, scaled hysteresis output
vc = (v - centre) / half-range, so the two are never fitted to the same thing: the asymmetry
even powers vc^2, vc^4; the saturation odd, saturating terms tanh(k vc) / k - vc, which flatten
both ends as a material that saturates does, where odd powers would need many terms (and
would turn back beyond the data).

Well beyond the range of the first fit the powers are held and the model continues linearly: a
polynomial extrapolated far past the data diverges. The tanh terms need no such limit.
"""

from typing import ClassVar

import jax.numpy as jnp
import numpy as np

from .effect import AbstractEffect

POLY_RANGE = 1.5
# The joint refinement's parameter for the centre the terms are taken about: it starts at the
# variable-projection fit's centre and moves with the rest, since an even power about a centre
# slightly off is partly odd, and the other way round.
CENTRE = "poly_centre"


def powers(v, norm, exponents):
    """The columns [vc^k for k in exponents] (T, len(exponents))."""
    vc = np.clip((v - norm[0]) / norm[1], -POLY_RANGE, POLY_RANGE)
    return np.column_stack([vc**k for k in exponents])


def power_slopes(v, norm, exponents):
    """The derivatives in v of `powers`' columns (T, len(exponents)): 0 where they are held."""
    raw = (v - norm[0]) / norm[1]
    vc = np.clip(raw, -POLY_RANGE, POLY_RANGE)
    der = np.column_stack([k * vc ** (k - 1) for k in exponents]) / norm[1]
    return der * (np.abs(raw) < POLY_RANGE)[:, None]


# Columns and derivatives are separate functions: the search evaluates the columns several times
# as often as the slopes, on records of every candidate, so neither pays for the other.
def saturating(v, norm, rates):
    """The columns [tanh(k vc) / k - vc for k in rates] (T, len(rates))."""
    vc = (v - norm[0]) / norm[1]
    return np.column_stack([np.tanh(k * vc) / k - vc for k in rates])


def saturating_slopes(v, norm, rates):
    """The derivatives in v of `saturating`'s columns (T, len(rates)): sech^2 - 1 = -tanh^2."""
    vc = (v - norm[0]) / norm[1]
    return np.column_stack([-(np.tanh(k * vc) ** 2) for k in rates]) / norm[1]


def _centred(v, theta, norm):
    return (v - theta.get(CENTRE, norm[0])) / norm[1]


def jax_powers(v, theta, norm, exponents):
    """The columns of `powers`, traceable, about the refined centre when `theta` has one."""
    vc = jnp.clip(_centred(v, theta, norm), -POLY_RANGE, POLY_RANGE)
    return jnp.stack([vc**k for k in exponents], axis=1)


def jax_saturating(v, theta, norm, rates):
    """The columns of `saturating`, traceable, about the refined centre when `theta` has one."""
    vc = _centred(v, theta, norm)
    return jnp.stack([jnp.tanh(k * vc) / k - vc for k in rates], axis=1)


def synth_output_map(v, y, f):
    """The hidden-effect generator's output map: `f` of the loop's centred, scaled output
    z = (v - centre) / half-range, back in v's units; returns (new v, y with the change)."""
    m = 0.5 * (v.max() + v.min())
    h = 0.5 * np.ptp(v)
    new = m + h * f((v - m) / h)
    # y holds v plus the terms before this one; (y - v) + new keeps them exactly.
    return new, (y - v) + new


class OutputMapEffect(AbstractEffect, abstract=True):
    """An effect whose output terms are columns of the centred output map (`terms`).

    They act before the plays too (an input envelope) and are bilinear with the play weights,
    so `model.fit` takes Gauss-Newton steps on them and refits the centre they are taken about.
    """

    play_side = True
    fit_iterations = 5
    bilinear = True
    # How many columns `terms` gives.
    n_terms: ClassVar[int]

    def terms(self, v, norm):
        """The columns (T, n_terms) at the hysteresis output `v`."""
        raise NotImplementedError

    def term_slopes(self, v, norm):
        """The derivatives in v of `terms`' columns (T, n_terms)."""
        raise NotImplementedError

    def n_columns(self, q):
        return self.n_terms

    def columns(self, q, p, v, drive, norm):
        return self.terms(v, norm)

    def drive(self, q, drive, v0, norm, coef):
        return drive + self.terms(v0, norm) @ coef

    def slope(self, q, v, norm, coef):
        return self.term_slopes(v, norm) @ coef
