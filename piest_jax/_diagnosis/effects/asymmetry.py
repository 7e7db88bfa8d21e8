"""Asymmetry: loops that are not point-symmetric (an input envelope and an even output polynomial).

Point symmetry is what an odd input map and an odd output map keep; the effect fits the even
parts: a quadratic term in the input before the plays and the even powers of the output after
them. An output that bends both ends alike is the saturation effect's.

On a record that traces one loop again and again (`Prepared.one_loop`) the envelope is left out:
that loop's asymmetry is as well given by the output's even powers, and the two forms differ
only on loops the record does not show (the envelope widens the minor loops on one side and
narrows them on the other), so the record cannot say which to carry over.
"""

import numpy as np

from ..output_map import OutputMapEffect, jax_powers, power_slopes, powers, synth_output_map

# The output polynomial's powers: the even ones, the part of an output map that breaks the
# loop's point symmetry (the odd ones are the saturation effect's).
POWERS = (2, 4)


class Asymmetry(OutputMapEffect):
    """g = u + b u^2 before the plays (q = b; None: no envelope) and y = v + [vc^2, vc^4] a
    after them."""

    name = "asymmetry"
    summary = "loops are not point-symmetric (input envelope, even output powers)"
    rank = 3
    listed = 5
    n_terms = len(POWERS)
    n_params = n_terms + 1

    def grid(self, p):
        if p.one_loop:
            return [None]
        return [0.0, -0.4, -0.2, 0.2, 0.4]

    def neighbours(self, q, level):
        if q is None:
            return []
        step = 0.1 * 0.5**level
        return [q - step, q + step]

    def describe(self, q):
        if q is None:
            return {"input_envelope": "left out: the record traces one loop"}
        return {"input_envelope_b": float(q)}

    def changes_plays(self, q):
        return bool(q)

    def input_map(self, q, g):
        return g if q is None else g + q * g**2

    def terms(self, v, norm):
        return powers(v, norm, POWERS)

    def term_slopes(self, v, norm):
        return power_slopes(v, norm, POWERS)

    def static(self, q):
        # Whether the envelope is there to refine.
        return q is not None

    def init_theta(self, q, coef):
        if q is None:
            return {"poly": coef}
        return {"envelope": np.asarray(float(q)), "poly": coef}

    def from_theta(self, q, theta):
        return (None if q is None else float(theta["envelope"])), [theta["poly"]]

    def jax_input(self, theta, static, g):
        if not static:
            return g
        return g + theta["envelope"] * g**2

    def jax_output(self, theta, static, y, v, data):
        return y + jax_powers(v, theta, data["norm"], POWERS) @ theta["poly"]

    def draw(self, prng, ctx):
        # Even forms only: an odd part would bend both ends alike, which is saturation.
        form = str(prng.choice(["quadratic", "envelope", "power", "cosh"]))
        state = {"form": form, "k": prng.uniform(0.25, 0.5) * prng.choice([-1, 1])}
        if form == "power":
            state["p"] = prng.uniform(1.3, 2.5)
        elif form == "cosh":
            state["c"] = prng.uniform(1.0, 2.5)
        return state

    def synth_input(self, state, ctx, chain):
        if state["form"] == "envelope":
            chain.g = chain.u + state["k"] * chain.u**2 / ctx.amp

    def synth_output(self, state, ctx, v, y):
        form, k = state["form"], state["k"]
        if form == "envelope":
            return v, y
        # Each stays monotone on the loop: the even term's slope is below 1 in size.
        if form == "quadratic":
            return synth_output_map(v, y, lambda z: z + 0.5 * k * (z**2 - 0.5))
        if form == "power":
            return synth_output_map(v, y, lambda z: z + k / state["p"] * np.abs(z) ** state["p"])
        c = state["c"]
        return synth_output_map(v, y, lambda z: z + k * (np.cosh(c * z) - 1.0) / (c * np.sinh(c)))
