"""Minor-loop non-congruence: loops of one size change shape with where they sit (a Preisach effect).

A PI operator is the Preisach model whose relay density depends only on a relay's width; then a
minor loop has the same shape wherever it sits. Real materials' densities also depend on a
relay's centre s, and every Preisach operator can be written through plays: each play's relays
of half-width r that are switched up are those centred below the play's output x_r, so the
relays of density mu(r, s) contribute F_r(x_r), with F_r' = mu(r, .). A density linear in the
centre adds x_r^2 to F_r, one that steps at centres s_k adds ramps (x_r - s_k)+: the model's play
terms are a few plays' outputs squared or through ramps at fixed band edges, with signed
coefficients. A loop at height x then grows or shrinks with x, which no PI weight and no function
of the whole output (asymmetry) reproduces for loops of several sizes at once; a record whose
loops all sit at one height cannot show it, and the search does not try it there.
"""

import jax.numpy as jnp
import numpy as np
from scipy.special import erf

from ..basis import THRESHOLDS
from ..effect import AbstractEffect
from ..scaling import MIN_SPREAD

# The plays whose relays' centre dependence the model fits, spread over the widths the
# normalised input ([-1, 1]) opens (r = 0.125 ... 0.69); the narrowest is left out, since a
# function of the input itself is a memoryless map that the asymmetry effect describes.
PLAYS = (2, 5, 8, 11)
# The grid: the density's form in the centre s (normalised input). Linear in s (each play's
# output squared), or piecewise constant, stepping at the band edges (ramps (x - s_k)+): smooth
# densities take the first, steps and narrow bumps the others. Eight bands resolve a bump a
# quarter of the range wide, which long, quiet records show and four bands leave at several
# times the noise.
FORMS = {
    "linear": None,
    "two_bands": (0.0,),
    "four_bands": (-0.5, 0.0, 0.5),
    "eight_bands": (-0.75, -0.5, -0.25, 0.0, 0.25, 0.5, 0.75),
}
# The samples the search needs per coefficient of a form larger than the charge the coarse
# forms share (the eight bands; see `grid`).
SAMPLES_PER_TERM = 40


def _terms(H, form, xp):
    """The play-term columns (edge-major for the bands), with `xp` NumPy or jax.numpy."""
    x = H[:, PLAYS]
    edges = FORMS[form]
    return [x * x] if edges is None else [xp.maximum(x - e, 0.0) for e in edges]


def _count(form) -> int:
    edges = FORMS[form]
    return len(PLAYS) * (1 if edges is None else len(edges))


class MinorLoopNoncongruence(AbstractEffect):
    """y gains sum_j c_j x_j^2, or sum_j sum_k c_jk (x_j - s_k)+, over a few plays x_j (q: the form).

    The terms are linear in their coefficients and act before the linear filters (a Preisach
    output, then dynamics); they carry over to another run, being functions of the plays.
    """

    name = "minor_loop_noncongruence"
    summary = "minor loops change shape with where they sit (a Preisach density that depends on the loop's centre)"
    rank = 8
    listed = 7
    # The coarse forms are charged alike, at the four bands' count, so the choice among them
    # rests on held-out error alone; the eight bands pay for each of their terms (`charge`).
    n_params = _count("four_bands")

    def unidentifiable(self, p):
        spread = p.spread
        if spread < MIN_SPREAD:
            return (
                f"the record's loops all sit at one height (reversal points spread over {spread:.0%} "
                f"of the input's range, below {MIN_SPREAD:.0%}): it cannot show how a loop's shape "
                "changes with where it sits"
            )
        return None

    def grid(self, p):
        # Held-out blocks of a short record do not tell 28 coefficients of four plays from a
        # memoryless map of the output: on 500 samples eight bands stood in for a saturation
        # and for an asymmetry. A form charged beyond the shared charge is tried where the
        # search has 40 samples per coefficient.
        return [f for f in FORMS if _count(f) <= self.n_params or len(p.y) >= SAMPLES_PER_TERM * _count(f)]

    def describe(self, q):
        return {
            "density_in_centre": q,
            "band_edges_normalised_input": list(FORMS[q] or ()),
            "play_thresholds_normalised_input": [float(THRESHOLDS[j]) for j in PLAYS],
        }

    def charge(self, q):
        return max(self.n_params, _count(q))

    def n_play_terms(self, q):
        return _count(q)

    def play_terms(self, q, H):
        return np.column_stack(_terms(H, q, np))

    def static(self, q):
        return q

    def init_theta(self, q, coef):
        return {"centre_terms": np.asarray(coef, float)}

    def from_theta(self, q, theta):
        return q, [theta["centre_terms"]]

    def jax_play_terms(self, theta, static, H):
        return jnp.concatenate(_terms(H, static, jnp), axis=1) @ theta["centre_terms"]

    def draw(self, prng, ctx):
        form = str(prng.choice(["exponential", "gaussian", "lorentzian"]))
        state = {
            "form": f"relay density {form} in the loop centre",
            "kind": form,
            # How the centre dependence grows with the relays' width: (r / r_max)^power.
            "power": prng.uniform(0.5, 1.5),
            "centre": prng.uniform(0.2, 0.6) * prng.choice([-1, 1]),
            "width": prng.uniform(0.25, 0.6),
            # The centre-dependent relays' share of the output's range.
            "share": prng.uniform(0.1, 0.3),
        }
        if form == "exponential":
            state["k"] = prng.uniform(1.0, 2.5) * prng.choice([-1, 1])
        else:  # a bump on the density, or a dip that keeps it positive
            state["k"] = prng.choice([prng.uniform(1.0, 3.0), -prng.uniform(0.5, 0.8)])
        return state

    def synth_play_terms(self, state, ctx, X, w):
        # Each play's relays weighted by a density f(s) of their centre s (input units scaled by
        # the amplitude): F(z) - z = integral of f - 1 from 0 to z, in closed form per family.
        z = X / ctx.amp
        k, c, b = state["k"], state["centre"], state["width"]
        if state["kind"] == "exponential":
            extra = np.expm1(k * z) / k - z
        elif state["kind"] == "gaussian":
            s = b * np.sqrt(2.0)
            extra = k * b * np.sqrt(np.pi / 2) * (erf((z - c) / s) - erf(-c / s))
        else:
            extra = k * b * (np.arctan((z - c) / b) - np.arctan(-c / b))
        d = (extra * (ctx.r / ctx.r.max()) ** state["power"]) @ w
        return d * state["share"] * np.ptp(X @ w) / max(np.ptp(d), 1e-300)
