"""Saturation: both ends of the loop flatten alike (a saturating input envelope and output terms).

A PI operator with positive weights has branches that steepen away from each reversal and grow
without bound; a material that saturates has branches that flatten at both ends, and loops that
close there. Before the plays that is an input that saturates, g = tanh(k (u - c)) / tanh(k) on
the normalised input (the plays then stop moving at the ends; the centre c, near the middle of
the input's range, is where the material is demagnetised or unpoled, which the record does not
say); after them an odd output map, tanh terms of the centred output (its even part is the
asymmetry effect's, `output_map.py`). Both keep the loop
point-symmetric, which is what tells saturation from asymmetry; both are functions of the input
and carry over to another run.
"""

import jax.numpy as jnp
import numpy as np

from ..effect import refinement_factor
from ..output_map import OutputMapEffect, jax_saturating, saturating, saturating_slopes, synth_output_map

# The output terms tanh(k vc) / k - vc: a mild and a strong flattening (with the linear term,
# they follow the generator's saturation curves to within 0.1 % of the range, RMS).
RATES = (1.5, 3.0)
# The input envelope's strength k: 0 is none; tanh(k) is 0.76, 0.95 and 0.99 at the others, the
# share of the slope left at the input's ends being 1 / cosh(k)^2.
STRENGTHS = (1.0, 1.8, 2.6)
# Its centre c on the normalised input, [-1, 1].
CENTRES = (-0.15, 0.0, 0.15)
NONE = (0.0, 0.0)


def envelope(g, k, c=0.0, xp=np):
    """tanh(k (g - c)) / tanh(k): with c = 0 it maps [-1, 1] onto itself, slope k / tanh(k) at 0;
    g itself at k = 0."""
    if xp is np and k == 0:
        return g
    return xp.tanh(k * (g - c)) / xp.tanh(k)


# The generator's strengths per form, from mild to a loop flattened over its outer third.
STRENGTH_RANGES = {
    "output tanh": (0.8, 2.2),
    "output Langevin": (2.0, 6.0),
    "output algebraic": (0.8, 2.5),
    "input tanh": (0.8, 2.2),
}


class Saturation(OutputMapEffect):
    """g = tanh(k (u - c)) / tanh(k) before the plays (q = (k, c); k = 0: none) and
    y = v + [tanh(k vc) / k - vc for k in RATES] a after them.
    """

    name = "saturation"
    summary = "both ends of the loop flatten alike (a saturating input envelope or output)"
    rank = 4
    listed = 8
    n_terms = len(RATES)
    n_params = n_terms + 2

    def grid(self, p):
        # On a record that traces one loop the envelope is left out, as the asymmetry
        # effect's is: the output terms shape that loop as well, and the two forms differ only
        # on loops the record does not show.
        if p.one_loop:
            return [NONE]
        return [NONE] + [(k, c) for k in STRENGTHS for c in CENTRES]

    def neighbours(self, q, level):
        k, c = q
        if k == 0:
            return []
        f, step = refinement_factor(level), 0.075 * 0.5**level
        return [(k / f, c), (k * f, c), (k, c - step), (k, c + step)]

    def describe(self, q):
        k, c = (float(v) for v in q)
        return {
            "input_envelope_k": k,
            "input_envelope_centre": c,
            "input_slope_left_at_ends": float(1.0 / np.cosh(k) ** 2),
        }

    def changes_plays(self, q):
        return q[0] > 0

    def input_map(self, q, g):
        return envelope(g, *q)

    def terms(self, v, norm):
        return saturating(v, norm, RATES)

    def term_slopes(self, v, norm):
        return saturating_slopes(v, norm, RATES)

    def static(self, q):
        # Whether the input envelope is there: its strength is refined on a log scale, which
        # cannot start from 0.
        return self.changes_plays(q)

    def init_theta(self, q, coef):
        k, c = q
        return {
            "log_envelope": np.asarray(np.log(k) if k else 0.0),
            "envelope_centre": np.asarray(float(c)),
            "saturating_terms": coef,
        }

    def from_theta(self, q, theta):
        if q[0] == 0:
            return NONE, [theta["saturating_terms"]]
        return (float(np.exp(theta["log_envelope"])), float(theta["envelope_centre"])), [theta["saturating_terms"]]

    def jax_input(self, theta, static, g):
        if not static:
            return g
        return envelope(g, jnp.exp(theta["log_envelope"]), theta["envelope_centre"], jnp)

    def jax_output(self, theta, static, y, v, data):
        return y + jax_saturating(v, theta, data["norm"], RATES) @ theta["saturating_terms"]

    def draw(self, prng, ctx):
        # Odd forms only: each end bends alike, the loop stays point-symmetric.
        form = str(prng.choice(list(STRENGTH_RANGES)))
        return {"form": form, "k": prng.uniform(*STRENGTH_RANGES[form])}

    def synth_input(self, state, ctx, chain):
        if state["form"] == "input tanh":
            chain.g = ctx.amp * np.tanh(state["k"] * chain.u / ctx.amp) / np.tanh(state["k"])

    def synth_output(self, state, ctx, v, y):
        form, k = state["form"], state["k"]
        if form == "input tanh":
            return v, y
        if form == "output tanh":
            return synth_output_map(v, y, lambda z: np.tanh(k * z) / np.tanh(k))
        if form == "output Langevin":  # the magnetisation curve of an ideal paramagnet
            return synth_output_map(v, y, lambda z: _langevin(k * z) / _langevin(k))
        return synth_output_map(v, y, lambda z: z / np.sqrt(1.0 + (k * z) ** 2) * np.sqrt(1.0 + k**2))


def _langevin(x):
    """coth(x) - 1/x, by its series near 0 where the difference cancels."""
    x = np.asarray(x, float)
    small = np.abs(x) < 1e-3
    safe = np.where(small, 1.0, x)
    return np.where(small, x / 3.0, 1.0 / np.tanh(safe) - 1.0 / safe)
