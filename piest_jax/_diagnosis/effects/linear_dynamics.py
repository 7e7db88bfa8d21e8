"""Linear dynamics: the output follows the hysteresis through a 1st- or 2nd-order lag (a resonance)."""

import functools

import jax.numpy as jnp
import jax.scipy.linalg as jsl
import numpy as np
from jax import lax
from scipy import signal as _signal

from .. import synthetic
from ..effect import AbstractEffect, refinement_factor


@functools.lru_cache(maxsize=4096)
def _discrete(spec, dt):
    """(b, a) of the filter discretised exactly for inputs linear between samples."""
    if spec[0] == "first":
        a = np.exp(-dt / spec[1])
        c = 1 - spec[1] * (1 - a) / dt
        return np.array([c, 1 - a - c]), np.array([1.0, -a])
    w, z = spec[1], spec[2]
    b, a, _ = _signal.cont2discrete(([w * w], [1.0, 2 * z * w, w * w]), dt, method="foh")
    return np.ravel(b), np.asarray(a)


def dynamics(X, spec, dt):
    """Columns of X through a unit-gain 1st or 2nd-order filter, starting at rest at X[0].

    **Arguments:** `X` (T, p); `spec`, `("first", tau)` or `("second", omega, zeta)` in seconds;
    `dt`, the sampling step.

    **Returns:** (T, p). The filter is discretised exactly for inputs linear between samples (a
    zero-order hold would add half a sample of lag, which would look like a delay).
    """
    b, a = _discrete(tuple(float(v) if not isinstance(v, str) else v for v in spec), float(dt))
    zi = _signal.lfilter_zi(b, a)
    return _signal.lfilter(b, a, X, axis=0, zi=zi[:, None] * X[:1])[0]


def dynamics_jax(v, kind, log_par, dt):
    """v through the filter of `dynamics` (kind "first"/"second", log parameters), traceable."""
    par = jnp.exp(log_par)
    if kind == "first":
        A, B = -jnp.ones((1, 1)) / par[0], jnp.ones((1,)) / par[0]
    else:
        om, ze = par[0], par[1]
        A = jnp.array([[0.0, 1.0], [-om * om, -2 * ze * om]])
        B = jnp.array([0.0, om * om])
    n = A.shape[0]
    # The state, the input and its slope evolve together linearly over one step: one exponential.
    M = jnp.zeros((n + 2, n + 2)).at[:n, :n].set(A).at[:n, n].set(B).at[n, n + 1].set(1.0)
    E = jsl.expm(M * dt)
    Phi, Gu, Gs = E[:n, :n], E[:n, n], E[:n, n + 1]
    slope = jnp.diff(v, append=v[-1:]) / dt
    x0 = jnp.zeros(n).at[0].set(v[0])

    def step(x, vs):
        return Phi @ x + Gu * vs[0] + Gs * vs[1], x[0]

    _, out = lax.scan(step, x0, (v, slope))
    return out


class LinearDynamics(AbstractEffect):
    """H(s) = 1/(tau s + 1) or w^2/(s^2 + 2 zeta w s + w^2) on the play columns; q = ("first", tau)
    or ("second", w, zeta), in seconds."""

    name = "linear_dynamics"
    summary = "the output follows through a 1st- or 2nd-order lag (a resonance)"
    rank = 5
    listed = 2
    n_params = 2

    def grid(self, p):
        taus = np.geomspace(0.3 * p.dt, 0.5 * p.period, 20)
        first = [("first", tau) for tau in taus]
        second = [("second", 1 / tau, z) for tau in taus[::2] for z in (0.2, 0.35, 0.5, 0.7, 1.0)]
        return first + second

    def neighbours(self, q, level):
        f = refinement_factor(level)
        if q[0] == "first":
            return [("first", q[1] / f), ("first", q[1] * f)]
        return [
            ("second", q[1] / f, q[2]),
            ("second", q[1] * f, q[2]),
            ("second", q[1], q[2] / f),
            ("second", q[1], min(q[2] * f, 1.5)),
        ]

    def describe(self, q):
        if q[0] == "first":
            return {"order": 1, "tau_s": float(q[1])}
        return {"order": 2, "omega_rad_s": float(q[1]), "zeta": float(q[2])}

    def linear(self, q, X, dt):
        return dynamics(X, q, dt)

    def static(self, q):
        return q[0]

    def init_theta(self, q, coef):
        return {"log_dynamics": np.log(np.asarray(q[1:], float))}

    def from_theta(self, q, theta):
        return (q[0], *(float(v) for v in np.exp(theta["log_dynamics"]))), []

    def jax_linear(self, theta, static, v, data):
        return dynamics_jax(v, static, theta["log_dynamics"], data["dt"])

    def draw(self, prng, ctx):
        wn = 2 * np.pi * ctx.f0 * prng.uniform(3, 8)
        zeta = prng.uniform(0.3, 0.9)
        if prng.random() < 0.5:
            return {"form": f"first order, tau = {1 / wn:.3g} s", "order": 1, "wn": wn}
        return {"form": f"second order, wn = {wn:.3g} rad/s, zeta = {zeta:.2f}", "order": 2, "wn": wn, "zeta": zeta}

    def synth_linear(self, state, ctx, v):
        if state["order"] == 1:
            return synthetic.lowpass(v, np.exp(-ctx.dt * state["wn"]))
        return synthetic.second_order(v, state["wn"], state["zeta"], ctx.dt)
