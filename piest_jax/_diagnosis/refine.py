"""Joint refinement of a diagnosis model by optimistix least squares.

The naming loop (`_diagnose`) fits every candidate by variable projection on a grid of its
nonlinear parameters: exact and global over the grid, but no finer than the grid and its pattern
search, and with the creep and output-polynomial terms linearised around the previous fit. Once
the effects are chosen, the model is refined here as one nonlinear least-squares problem solved
by optimistix (Levenberg-Marquardt by default, as in `fit_pi`): the play weights, the offset and
every effect's parameters (delay, time constants, damping, rate gain and exponent, envelope,
history turning points, creep time constants) move together, differentiated through the scans.
The model is the exact one of `_effects` (the same equations, normalised units): the creep
follows the current output, not the previous fit's.

Positive quantities are carried as logarithms (times, gains) or through a softplus (play weights
and creep coefficients, which `_effects` keeps >= 0), so every step stays physical.
"""

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl
import numpy as np
import optimistix as optx
from jax import lax

from . import effects as _effects
from .._identification.fit import _softplus_inv, _solver, result_name
from .._identification.fit_data import pad_count

SOLVERS = ("lm", "gn", "bfgs")


class Structure(NamedTuple):
    """The static shape of a configuration: which terms exist and in which form."""

    asymmetry: bool
    rate_form: str | None
    n_turns: int
    delay: bool
    dynamics: str | None
    n_creep: int
    drift: bool


def structure(cfg) -> Structure:
    """The `Structure` of a configuration (dict effect -> grid parameters)."""
    rate = cfg.get("rate_dependence")
    dyn = cfg.get("linear_dynamics")
    return Structure(
        "asymmetry" in cfg, None if rate is None else rate[0],
        len(cfg["initial_state"]) if "initial_state" in cfg else 0,
        "delay" in cfg, None if dyn is None else dyn[0],
        len(cfg["creep"]) if "creep" in cfg else 0, "offset_drift" in cfg,
    )


def initial_params(cfg, w) -> dict:
    """The parameters of a configuration and its `_effects.fit` coefficients `w` (normalised units)."""
    w = np.asarray(w, float)
    n = _effects.N_PLAYS
    # A coefficient the sign-constrained fit left at exactly 0 would sit where the softplus is
    # flat and never move; starting it at a thousandth of the largest lets the solver use it.
    floor = 1e-3 * max(float(np.max(np.abs(w[:n]))), 1e-300)
    theta = {"weights": _softplus_inv(np.maximum(w[:n], floor)), "offset": np.asarray(w[n])}
    k = n + 1
    if "asymmetry" in cfg:
        theta["envelope"] = np.asarray(float(cfg["asymmetry"]))
        theta["poly"] = w[k : k + _effects.N_POLY]
        k += _effects.N_POLY
    if "creep" in cfg:
        c = w[k : k + len(cfg["creep"])]
        theta["creep"] = _softplus_inv(np.maximum(c, 1e-3 * max(float(np.max(np.abs(c))), 1e-12)))
        theta["log_creep_tau"] = np.log(np.asarray(cfg["creep"], float))
        k += len(cfg["creep"])
    if "offset_drift" in cfg:
        theta["drift"] = w[k : k + _effects.N_DRIFT]
    if "rate_dependence" in cfg:
        _, gain, exponent = cfg["rate_dependence"]
        theta["log_rate"] = np.log(np.asarray([gain, exponent], float))
    if "initial_state" in cfg:
        theta["turns"] = np.asarray(cfg["initial_state"], float)
    if "delay" in cfg:
        theta["log_delay"] = np.log(np.asarray(float(cfg["delay"])))
    dyn = cfg.get("linear_dynamics")
    if dyn is not None:
        theta["log_dynamics"] = np.log(np.asarray(dyn[1:], float))
    return {k: jnp.asarray(v) for k, v in theta.items()}


def to_config(cfg, theta) -> tuple[dict, np.ndarray]:
    """The configuration and `_effects` coefficient vector that a parameter set stands for."""
    t = {k: np.asarray(v, float) for k, v in theta.items()}
    cfg = dict(cfg)

    def softplus(v):
        return np.asarray(jax.nn.softplus(v), float)

    w = [softplus(t["weights"]), [t["offset"]]]
    if "envelope" in t:
        cfg["asymmetry"] = float(t["envelope"])
        w.append(t["poly"])
    if "creep" in t:
        cfg["creep"] = tuple(float(v) for v in np.exp(t["log_creep_tau"]))
        w.append(softplus(t["creep"]))
    if "drift" in t:
        w.append(t["drift"])
    if "log_rate" in t:
        gain, exponent = np.exp(t["log_rate"])
        cfg["rate_dependence"] = (cfg["rate_dependence"][0], float(gain), float(exponent))
    if "turns" in t:
        cfg["initial_state"] = tuple(float(v) for v in t["turns"])
    if "log_delay" in t:
        cfg["delay"] = float(np.exp(t["log_delay"]))
    if "log_dynamics" in t:
        cfg["linear_dynamics"] = (cfg["linear_dynamics"][0], *(float(v) for v in np.exp(t["log_dynamics"])))
    return cfg, np.concatenate([np.atleast_1d(np.asarray(v, float)) for v in w])


def _history_states(g0, turns):
    r = jnp.asarray(_effects.THRESHOLDS, g0.dtype)
    x = jnp.full(r.shape, g0)
    for a in [*turns, g0]:
        x = jnp.clip(x, a - r, a + r)
    return x


def _rate_power(rho, exponent):
    # rho^p with rho = 0 allowed: the power's gradient in p is rho^p log(rho), zero there.
    pos = rho > 0
    safe = jnp.where(pos, rho, 1.0)
    return jnp.where(pos, jnp.exp(exponent * jnp.log(safe)), 0.0)


def _hysteresis(theta, st: Structure, u, rho):
    """The weighted plays plus offset, before delay and dynamics (T,)."""
    r0 = jnp.asarray(_effects.THRESHOLDS, u.dtype)
    g = u + theta["envelope"] * u**2 if st.asymmetry else u
    if st.rate_form is None:
        r = jnp.broadcast_to(r0, (u.shape[0], r0.shape[0]))
    else:
        gain, exponent = jnp.exp(theta["log_rate"][0]), jnp.exp(theta["log_rate"][1])
        rp = _rate_power(rho, exponent)[:, None]
        r = r0[None, :] * (1 + gain * rp) if st.rate_form == "scale" else r0[None, :] + gain * rp
    x0 = _history_states(g[0], list(theta["turns"])) if st.n_turns else jnp.full(r0.shape, g[0])
    w = jax.nn.softplus(theta["weights"])

    def step(x, gr):
        x = jnp.clip(x, gr[0] - gr[1], gr[0] + gr[1])
        return x, jnp.dot(w, x)

    _, v = lax.scan(step, x0, (g, r))
    return v + theta["offset"]


def _delayed(v, d):
    """v delayed by d >= 0 samples, linear interpolation, the start held (as `_effects.delayed`)."""
    k = jnp.floor(d)
    f = d - k
    idx = jnp.arange(v.shape[0])
    a = v[jnp.clip(idx - k.astype(idx.dtype), 0, None)]
    b = v[jnp.clip(idx - k.astype(idx.dtype) - 1, 0, None)]
    return (1 - f) * a + f * b


def _filtered(v, kind, log_par, dt):
    """v through a unit-gain 1st/2nd-order filter, exact for v linear between samples, from rest."""
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


def _lowpass(v, lam):
    def step(y, vt):
        y = lam * y + (1 - lam) * vt
        return y, y

    return lax.scan(step, jnp.full(lam.shape, v[0]), v)[1]


def _poly(v, norm):
    vc = jnp.clip((v - norm[0]) / norm[1], -_effects.POLY_RANGE, _effects.POLY_RANGE)
    return jnp.stack([vc**k for k in range(2, 2 + _effects.N_POLY)], axis=1)


def model(theta, st: Structure, data, *, transferable_only=False):
    """The model's output (T,) in normalised units.

    **Arguments:** `theta`, the parameters (`initial_params`); `st`, the `Structure`; `data`, a
    dict with `u`, `rho`, `s` (T,) and the scalars `dt`, `norm`; `transferable_only`, switch off
    the identification record's own history (relaxed plays) and drift.

    **Returns:** the output (T,).
    """
    if transferable_only and st.n_turns:
        st = st._replace(n_turns=0)
    v = _hysteresis(theta, st, data["u"], data["rho"])
    if st.delay:
        v = _delayed(v, jnp.exp(theta["log_delay"]) / data["dt"])
    if st.dynamics is not None:
        v = _filtered(v, st.dynamics, theta["log_dynamics"], data["dt"])
    if st.asymmetry:
        v = v + _poly(v, data["norm"]) @ theta["poly"]
    if st.n_creep:
        lam = jnp.exp(-data["dt"] / jnp.exp(theta["log_creep_tau"]))
        c = jax.nn.softplus(theta["creep"])
        v = v + (_lowpass(v, lam) - v[:, None]) @ c
    if st.drift and not transferable_only:
        k = jnp.arange(1, _effects.N_DRIFT + 1)
        v = v + jnp.cos(jnp.pi * data["s"][:, None] * k[None, :]) @ theta["drift"]
    return v


def data_of(p: _effects.Prepared, norm, *, pad: bool = True):
    """The arrays `model` reads, padded to a length shared by nearby lengths, and the mask."""
    T = len(p.u)
    extra = pad_count(T) if pad else 0
    # Padding repeats the last input (no play moves) at zero rate; its residuals are masked out.
    ext = lambda a, v: np.concatenate([a, np.full(extra, v)])  # noqa: E731
    data = dict(u=ext(p.u, p.u[-1]), rho=ext(p.rho, 0.0), s=ext(p.s, p.s[-1]),
                dt=np.asarray(p.dt), norm=np.asarray(norm, float))
    y = ext(p.y, 0.0)
    mask = ext(np.ones(T), 0.0)
    return {k: jnp.asarray(v) for k, v in data.items()}, jnp.asarray(y), jnp.asarray(mask)


def _residuals(theta, args):
    st, data, y, mask = args
    return mask * (model(theta, st, data) - y) / jnp.sqrt(jnp.sum(mask))


@eqx.filter_jit
def _solve(theta0, st, data, y, mask, *, solver, max_steps, rtol, atol):
    args = (st, data, y, mask)
    sol = optx.least_squares(_residuals, _solver(solver, rtol, atol), theta0, args=args,
                             max_steps=max_steps, throw=False)
    loss0 = jnp.sum(_residuals(theta0, args) ** 2)
    loss = jnp.sum(_residuals(sol.value, args) ** 2)
    return sol.value, sol.result, sol.stats["num_steps"], loss0, loss


class Refined(NamedTuple):
    """A refined model: its parameters and how the solve went (RMSEs in normalised units)."""

    theta: dict
    structure: Structure
    cfg: dict
    result: str
    steps: int
    rmse_start: float
    rmse: float
    accepted: bool


def refine(p: _effects.Prepared, cfg, w, norm, *, solver: str = "lm", max_steps: int = 100,
           rtol: float = 1e-6, atol: float = 1e-9) -> Refined:
    """Refine a configuration fitted by `_effects.fit` jointly, by optimistix least squares.

    **Arguments:**

    - `p`: the record (normalised units, full rate).
    - `cfg`, `w`, `norm`: the configuration, its coefficients and the output polynomial's
      normalisation, from `_effects.fit`.
    - `solver`: `"lm"` (Levenberg-Marquardt), `"gn"` (Gauss-Newton) or `"bfgs"`.
    - `max_steps`, `rtol`, `atol`: the solver's step limit and tolerances (normalised units;
      the defaults are `fit_pi`'s, and `atol` bounds the mean squared error's last change, far
      below any measured record's noise).

    **Returns:** a `Refined`; `accepted` is False (and `theta` the start) when the solve did not
    lower the error of the exact model at the starting point, or gave a non-finite result; the
    caller then keeps the variable-projection fit.
    """
    if solver not in SOLVERS:
        raise ValueError(f"unknown solver {solver!r}; choose one of {SOLVERS}")
    st = structure(cfg)
    theta0 = initial_params(cfg, w)
    data, y, mask = data_of(p, norm)
    theta, result, steps, loss0, loss = _solve(theta0, st, data, y, mask, solver=solver,
                                               max_steps=max_steps, rtol=rtol, atol=atol)
    loss0, loss = float(loss0), float(loss)
    finite = np.isfinite(loss) and all(bool(jnp.all(jnp.isfinite(v))) for v in theta.values())
    accepted = bool(finite and loss < loss0)
    if not accepted:
        theta, loss = theta0, loss0
    new_cfg, _ = to_config(cfg, theta)
    return Refined(theta, st, new_cfg, result_name(result), int(steps), float(np.sqrt(loss0)),
                   float(np.sqrt(loss)), accepted)


def predict(refined: Refined, p: _effects.Prepared, norm, *, transferable_only=False,
            history=None) -> np.ndarray:
    """The refined model's output on a record (normalised units, (T,)).

    **Arguments:** `refined`; `p`, a record in the identification record's units; `norm`, the
    output polynomial's normalisation; `transferable_only`, as in `model`; `history`, turning
    points of an input history that sets the plays' initial states on this record (as the
    `initial_state` effect does), which implies `transferable_only` for the drift.

    **Returns:** the output (T,).
    """
    data, _, _ = data_of(p, norm, pad=False)
    theta, st = refined.theta, refined.structure
    if history is not None:
        theta = {**theta, "turns": jnp.asarray(history, data["u"].dtype)}
        st = st._replace(n_turns=len(history), drift=False)
        transferable_only = False
    return np.asarray(_predict_jit(theta, st, data, transferable_only))


@eqx.filter_jit
def _predict_jit(theta, st, data, transferable_only):
    return model(theta, st, data, transferable_only=transferable_only)
