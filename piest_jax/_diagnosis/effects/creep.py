"""Creep: after a change the output keeps moving slowly, driven by the input or by the output.

Two drives, each a bank of first-order lags, chosen by the search on held-out blocks as it
chooses any form:

- **input**: y = v + sum_k c_k (lag_tau_k(u) - u), signed c_k: the creep operator of
  `piest fit --model pi+creep` ([`piest_jax.Creep`][]), its time constants held where the fit
  holds them (`_identification.time_constants`: ordered, at least half a decade apart, none
  faster than the input reverses). What the diagnosis names in this form is the component
  `piest fit` fits.
- **output**: y = v + sum_k c_k (lag_tau_k(v) - v), c_k >= 0, v the output before creep: a slow
  yield of the displacement itself, following every change of the output in its direction.

Both are functions of the input and carry over to another run. They differ where the output
does not follow the input one to one: through the plays' memory a lag of the output creeps
after a reversal by the loop's own step, a lag of the input by the input's.
"""

import jax
import jax.numpy as jnp
import numpy as np

from ..._identification.fit import _softplus_inv
from ..._identification.time_constants import (
    LAG_RATIO,
    initial_time_constants,
    lag_base,
    lag_log_tau,
    lag_theta,
)
from ..._models.creep import lag_states
from .. import synthetic
from ..effect import AbstractEffect, refinement_factor

N_OUTPUT_MODES = 5  # lags of the output, log-spaced from a tenth of the input's period to the record's length
N_INPUT_LAGS = 3  # lags of the input, as many as `piest fit --model auto` tries at most
N_STARTS = 4  # placements of the input lags across the time constants the search starts from


# Compiled once per shape: the search calls it thousands of times on NumPy arrays, where each
# eager call would trace the scan again (a third of a search's time, for the same numbers).
@jax.jit
def lowpass(v, lam):
    """First-order low-pass y_t = lam y_t-1 + (1 - lam) v_t from rest at v_0, `lam` (k,) -> (T, k).

    The creep operator's lag recurrence ([`piest_jax.Creep`][]), so the diagnosis and the fitted
    model share one definition; traceable in `v` and `lam`.
    """
    v = jnp.asarray(v)
    lam = jnp.asarray(lam, v.dtype)
    return lag_states(v, lam, jnp.full(lam.shape, v[0]), method="scan")


class Lags(tuple):
    """Time constants (s) with what drives them ("input" or "output") and, for the input's,
    the fastest time constant the record allows (`shortest_time_constant`)."""

    drive: str
    shortest: float

    def __new__(cls, taus, drive: str, shortest: float = 0.0):
        self = super().__new__(cls, (float(v) for v in taus))
        self.drive, self.shortest = drive, float(shortest)
        return self

    def __getnewargs__(self):
        return (tuple(self), self.drive, self.shortest)

    def allowed(self) -> bool:
        """Whether input lags keep the fit's bounds (fastest >= shortest, ratios >= LAG_RATIO)."""
        q = np.asarray(self, float)
        return bool(q[0] >= self.shortest * (1 - 1e-9) and np.all(q[1:] >= q[:-1] * LAG_RATIO * (1 - 1e-9)))


class Creep(AbstractEffect):
    """y = v + sum_k c_k (lag_tau_k(d) - d), d the input (signed c_k) or the output before
    creep (c_k >= 0); q = [`Lags`][]: the time constants (s) and the drive.

    Each term is zero while its drive rests long enough, so the static loop stays the plays'.
    A positive coefficient is an output that keeps moving after a change in the direction of
    the change; a negative one (input lags only) an output that overshoots and relaxes back.
    """

    name = "creep"
    summary = "after a change the output keeps moving slowly (lags of the input or of the output)"
    rank = 6
    listed = 4
    # Charged at its larger form: three input lags, each a coefficient and a time constant.
    n_params = max(N_OUTPUT_MODES, 2 * N_INPUT_LAGS)
    fit_iterations = 2

    def grid(self, p):
        duration = p.t[-1] - p.t[0]
        out = Lags(np.geomspace(min(0.1 * p.period, duration / 10), duration, N_OUTPUT_MODES), "output")
        lo = p.shortest_lag
        # Every other of twice as many starts: those with no lag on its bound, where the
        # refinement's parametrisation would start it just above (`time_constants.lag_theta`).
        taus = initial_time_constants(N_INPUT_LAGS, p.dt, duration, lo, n_starts=2 * N_STARTS)[1::2]
        return [out, *(q for q in (Lags(row, "input", lo) for row in taus) if q.allowed())]

    def neighbours(self, q, level):
        if q.drive == "output":
            return []
        # One lag moved at a time, and all of them together; a move that breaks the bounds is
        # left out.
        f = refinement_factor(level)
        moves = [[f**s if i == k else 1.0 for i in range(len(q))] for k in range(len(q)) for s in (-1, 1)]
        moves += [[f**s] * len(q) for s in (-1, 1)]
        near = (Lags(np.asarray(q) * np.asarray(m), "input", q.shortest) for m in moves)
        return [n for n in near if n.allowed()]

    def describe(self, q):
        return {"drive": q.drive, "time_constants_s": [float(v) for v in q]}

    def positive_terms(self, q):
        return q.drive == "output"

    def n_columns(self, q):
        return len(q)

    def columns(self, q, p, v, drive, norm):
        if q.drive == "output":
            return np.asarray(lowpass(drive, np.exp(-p.dt / np.asarray(q)))) - drive[:, None]
        # Lags of the input are the same at every iteration of every fit the search makes with
        # them: computed once per record (read-only, as they are shared).
        key = ("creep_input_lags", tuple(q))
        if key not in p.cache:
            cols = np.asarray(lowpass(p.u, np.exp(-p.dt / np.asarray(q)))) - p.u[:, None]
            cols.flags.writeable = False
            p.cache[key] = cols
        return p.cache[key]

    def transients(self, q, p):
        # A lag starting away from rest adds lam^(t+1) times its initial offset.
        lam = np.exp(-p.dt / np.asarray(q, float))
        return lam[None, :] ** (np.arange(len(p.u))[:, None] + 1)

    def static(self, q):
        return (len(q), q.drive, q.shortest)

    # The refinement moves input lags through the fit's parametrisation
    # (`time_constants.lag_log_tau`), so they keep its bounds at every step; output lags
    # through their logarithms, their coefficients through a softplus (kept >= 0).

    def init_theta(self, q, coef):
        if q.drive == "input":
            base = lag_base(len(q), q.shortest)
            return {"creep": np.asarray(coef, float), "creep_lag": np.asarray(lag_theta(np.log(np.asarray(q)), base))}
        # A coefficient at exactly 0 would sit where the softplus is flat and never move.
        c = np.maximum(coef, 1e-3 * max(float(np.max(np.abs(coef))), 1e-12))
        return {"creep": _softplus_inv(c), "log_creep_tau": np.log(np.asarray(q, float))}

    def from_theta(self, q, theta):
        if q.drive == "input":
            log_tau = lag_log_tau(jnp.asarray(theta["creep_lag"]), lag_base(len(q), q.shortest))
            return Lags(np.exp(np.asarray(log_tau)), "input", q.shortest), [np.asarray(theta["creep"], float)]
        taus = np.exp(theta["log_creep_tau"])
        return Lags(taus, "output"), [np.asarray(jax.nn.softplus(theta["creep"]), float)]

    def jax_output(self, theta, static, y, v, data):
        n, drive, shortest = static
        if drive == "input":
            # Lags of the input, as in `columns`.
            d = data["u"]
            lam = jnp.exp(-data["dt"] / jnp.exp(lag_log_tau(theta["creep_lag"], lag_base(n, shortest))))
            return y + (lowpass(d, lam) - d[:, None]) @ theta["creep"]
        # Driven by the output so far (after the output map), as in `columns`.
        lam = jnp.exp(-data["dt"] / jnp.exp(theta["log_creep_tau"]))
        return y + (lowpass(y, lam) - y[:, None]) @ jax.nn.softplus(theta["creep"])

    def draw(self, prng, ctx):
        c = prng.uniform(0.08, 0.2)
        taus = ctx.t[-1] * np.array([prng.uniform(0.01, 0.04), prng.uniform(0.1, 0.4)])
        t0 = prng.uniform(0.2, 1.0) / max(ctx.f0, 1e-9) / 10
        which = prng.random()
        if which < 0.5:
            return {"form": "two slow exponential modes", "c": c, "taus": taus}
        if which < 0.75:
            return {"form": "logarithmic, log(1 + t/t0)", "c": c, "t0": t0, "drive": "output"}
        return {"form": "logarithmic in the input's steps", "c": c, "t0": t0, "drive": "input"}

    def synth_output(self, state, ctx, v, y):
        c = state["c"]
        if "taus" in state:
            return v, y + c * sum(synthetic.lowpass(v, np.exp(-ctx.dt / tau)) - v for tau in state["taus"]) * 0.5
        # Logarithmic creep: every change keeps growing as log(1 + t/t0), a change of the output
        # (the displacement yields) or of the input (the drive's steps; scaled by the plain
        # operator's gain, so that its size matches the other forms').
        kern = np.log1p(np.arange(len(ctx.t)) * ctx.dt / state["t0"])
        kern = kern / kern[-1]
        d = v if state["drive"] == "output" else ctx.u * ctx.span0 / max(np.ptp(ctx.u), 1e-300)
        return v, y + c * 1.5 * np.convolve(np.diff(d, prepend=d[0]), kern)[: len(ctx.t)]
