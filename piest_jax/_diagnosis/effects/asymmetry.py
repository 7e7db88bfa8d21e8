"""Asymmetry: loops that are not point-symmetric (an input envelope and an output polynomial)."""

import jax.numpy as jnp
import numpy as np

from ..effect import AbstractEffect

N_POLY = 4  # output polynomial terms v^2 .. v^5
POLY_RANGE = 1.5


def poly(v, norm):
    """Output polynomial columns [vc^2 .. vc^(N_POLY+1)] and their derivatives in v.

    vc = (v - norm[0]) / norm[1]. Well beyond the range of the first fit, the polynomial is held
    (the model continues linearly): a polynomial extrapolated far past the data diverges.
    """
    raw = (v - norm[0]) / norm[1]
    vc = np.clip(raw, -POLY_RANGE, POLY_RANGE)
    pw = [np.ones_like(vc), vc]
    for _ in range(N_POLY):
        pw.append(pw[-1] * vc)
    cols = np.column_stack(pw[2:])
    der = np.column_stack([k * pw[k - 1] for k in range(2, 2 + N_POLY)]) / norm[1]
    return cols, der * (np.abs(raw) < POLY_RANGE)[:, None]


def poly_jax(v, norm):
    """The columns of `poly`, traceable."""
    vc = jnp.clip((v - norm[0]) / norm[1], -POLY_RANGE, POLY_RANGE)
    return jnp.stack([vc**k for k in range(2, 2 + N_POLY)], axis=1)


class Asymmetry(AbstractEffect):
    """g = u + b u^2 before the plays (q = b) and y = v + [v^2 .. v^5] a after them.

    The output polynomial is bilinear with the play weights, so `model.fit` takes Gauss-Newton
    steps on it.
    """

    name = "asymmetry"
    summary = "loops are not point-symmetric (input envelope, output polynomial)"
    rank = 3
    listed = 5
    n_params = N_POLY + 1
    play_side = True
    fit_iterations = 5
    bilinear = True

    def grid(self, p):
        return [0.0, -0.4, -0.2, 0.2, 0.4]

    def neighbours(self, q, level):
        step = 0.1 * 0.5**level
        return [q - step, q + step]

    def describe(self, q):
        return {"input_envelope_b": float(q)}

    def changes_plays(self, q):
        return bool(q)

    def input_map(self, q, g):
        return g + q * g**2

    def n_columns(self, q):
        return N_POLY

    def columns(self, q, p, v, drive, norm):
        return poly(v, norm)[0]

    def drive(self, q, drive, v0, norm, coef):
        return drive + poly(v0, norm)[0] @ coef

    def slope(self, q, v, norm, coef):
        return poly(v, norm)[1] @ coef

    def init_theta(self, q, coef):
        return {"envelope": np.asarray(float(q)), "poly": coef}

    def from_theta(self, q, theta):
        return float(theta["envelope"]), [theta["poly"]]

    def jax_input(self, theta, static, g):
        return g + theta["envelope"] * g**2

    def jax_output(self, theta, static, v, data):
        return v + poly_jax(v, data["norm"]) @ theta["poly"]

    def draw(self, prng, ctx):
        form = str(prng.choice(["saturation", "quadratic", "envelope", "exponential"]))
        return {"form": form, "k": prng.uniform(0.25, 0.5) * prng.choice([-1, 1])}

    def synth_input(self, state, ctx, chain):
        if state["form"] == "envelope":
            chain.g = chain.u + state["k"] * chain.u**2 / ctx.amp

    def synth_output(self, state, ctx, v, y):
        form, k_asym = state["form"], state["k"]
        if form == "envelope":
            return v, y
        m = 0.5 * (v.max() + v.min())
        h = 0.5 * np.ptp(v)
        z = (v - m) / h
        if form == "saturation":
            k = 0.8 + 1.4 * abs(k_asym)
            z = np.tanh(k * z) / np.tanh(k)
        elif form == "quadratic":
            z = z + 0.5 * k_asym * (z**2 - 0.5)
        else:
            k = (0.5 + 2 * abs(k_asym)) * np.sign(k_asym)
            z = np.expm1(k * z) / k
        new = m + h * z
        # y holds v plus the terms before this one; (y - v) + new keeps them exactly.
        return new, (y - v) + new
