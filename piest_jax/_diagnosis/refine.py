"""Joint refinement of a diagnosis model by optimistix least squares.

The naming loop (`diagnose`) fits every candidate by variable projection on a grid of its
nonlinear parameters: exact and global over the grid, but no finer than the grid and its pattern
search, and with the creep and output-map terms linearised around the previous fit. Once
the effects are chosen, the model is refined here as one nonlinear least-squares problem solved
by optimistix (Levenberg-Marquardt by default, as in `fit_pi`): the play weights, the offset and
every effect's parameters (delay, time constants, damping, rate gain and exponent, envelopes,
history turning points, creep time constants) move together, differentiated through the scans.
The model is the exact one of `model` (each effect's JAX hooks state the same equations as its
NumPy ones, normalised units): the creep follows the current output, not the previous fit's.

Positive quantities are carried as logarithms (times, gains) or through a softplus (play weights
and creep coefficients, which `model` keeps >= 0), so every step stays physical; the play weights
of a clockwise loop (`Prepared.signed`) are free.
"""

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from .._identification.fit import _softplus_inv
from .._identification.fit_data import pad_count
from .._identification.solvers import SOLVERS as SOLVERS
from .._identification.solvers import check_solver, least_squares_solver, result_name
from .._operators.play import _bank
from .basis import N_PLAYS, THRESHOLDS
from .effects import EFFECT, chain
from .model import coefficient_slices
from .output_map import CENTRE, OutputMapEffect
from .scaling import Prepared

# The static shape of a configuration: (effect name, static form) pairs in chain order, which
# fix which terms exist and in which form (hashable, so it is a static argument of the solve).
Structure = tuple


def structure(cfg) -> Structure:
    """The `Structure` of a configuration (dict effect -> grid parameters)."""
    return tuple((e.name, e.static(cfg[e.name])) for e in chain(cfg))


def _transferable(st: Structure) -> Structure:
    """The structure without the effects tied to the identification record."""
    return tuple((n, s) for n, s in st if not EFFECT[n].record_specific)


def initial_params(cfg, w, signed: bool = False) -> dict:
    """The parameters of a configuration and its `model.fit` coefficients `w` (normalised units).

    The play weights are `weights` (through a softplus, >= 0) or, with `signed` (a clockwise
    loop, `Prepared.signed`), `signed_weights` as they are; the key fixes the model's form.
    """
    w = np.asarray(w, float)
    n = N_PLAYS
    if signed:
        theta = {"signed_weights": w[:n], "offset": np.asarray(w[n])}
    else:
        # A weight the sign-constrained fit left at exactly 0 would sit where the softplus is
        # flat and never move; starting it at a thousandth of the largest lets the solver use it.
        floor = 1e-3 * max(float(np.max(np.abs(w[:n]))), 1e-300)
        theta = {"weights": _softplus_inv(np.maximum(w[:n], floor)), "offset": np.asarray(w[n])}
    slices = coefficient_slices(cfg)
    for e in chain(cfg):
        sl = slices.get(e.name)
        theta.update(e.init_theta(cfg[e.name], w[sl] if sl is not None else w[:0]))
    return {k: jnp.asarray(v) for k, v in theta.items()}


def to_config(cfg, theta) -> tuple[dict, np.ndarray]:
    """The configuration and `model` coefficient vector that a parameter set stands for."""
    t = {k: np.asarray(v, float) for k, v in theta.items()}
    cfg = dict(cfg)
    w = [np.asarray(_play_weights(t), float), [t["offset"]]]
    # In the coefficient vector's order (`model.coefficient_slices`); effects without
    # coefficients add none wherever they come.
    order = list(coefficient_slices(cfg))
    for e in sorted(chain(cfg), key=lambda e: order.index(e.name) if e.name in order else -1):
        cfg[e.name], coef = e.from_theta(cfg[e.name], t)
        w.extend(coef)
    return cfg, np.concatenate([np.atleast_1d(np.asarray(v, float)) for v in w])


def _play_weights(theta):
    """The play weights of a parameter set: signed, or >= 0 through the softplus."""
    if "signed_weights" in theta:
        return theta["signed_weights"]
    return jax.nn.softplus(theta["weights"])


def _hysteresis(theta, st: Structure, u, rho):
    """The weighted plays, offset and play terms, before the linear filters (T,)."""
    r0 = jnp.asarray(THRESHOLDS, u.dtype)
    effects = [(EFFECT[n], s) for n, s in st]
    g = u
    for e, s in effects:
        g = e.jax_input(theta, s, g)
    r = jnp.broadcast_to(r0, (u.shape[0], r0.shape[0]))
    for e, s in effects:
        r = e.jax_thresholds(theta, s, r, r0, rho)
    x0 = jnp.full(r0.shape, g[0])
    for e, s in effects:
        x0 = e.jax_initial_states(theta, s, g[0], x0)
    # The operator's own recurrence (the scan: thresholds that vary over time do not take the
    # kernel, and the solver differentiates through it), without `play`'s checks of traced
    # values: a check is a host callback, which keeps the program out of the persistent
    # compilation cache of `piest diagnose`. The inputs are finite by construction (the record
    # is checked, the parameters are logarithms and softpluses, thresholds cannot turn
    # negative). A step whose parameters overflow gives a non-finite loss (infinite thresholds
    # times a rate of zero), which the solver does not take and `refine` would not accept,
    # where the checks raised and ended the diagnosis.
    H = _bank(g, r, x0, "scan")
    v = H @ _play_weights(theta) + theta["offset"]
    for e, s in effects:
        extra = e.jax_play_terms(theta, s, H)
        if extra is not None:
            v = v + extra
    return v


def model(theta, st: Structure, data, *, transferable_only=False):
    """The model's output (T,) in normalised units.

    **Arguments:** `theta`, the parameters (`initial_params`); `st`, the `Structure`; `data`, a
    dict with `u`, `rho`, `s` (T,) and the scalars `dt`, `norm`; `transferable_only`, switch off
    the effects tied to the identification record (its history, its drift).

    **Returns:** the output (T,).
    """
    if transferable_only:
        st = _transferable(st)
    v = _hysteresis(theta, st, data["u"], data["rho"])
    for n, s in st:
        v = EFFECT[n].jax_linear(theta, s, v, data)
    y = v
    for n, s in st:
        y = EFFECT[n].jax_output(theta, s, y, v, data)
    return y


def data_of(p: Prepared, norm, *, pad: bool = True):
    """The arrays `model` reads, padded to a length shared by nearby lengths, and the mask."""
    T = len(p.u)
    extra = pad_count(T) if pad else 0
    # Padding repeats the last input (no play moves) at zero rate; its residuals are masked out.
    ext = lambda a, v: np.concatenate([a, np.full(extra, v)])  # noqa: E731
    data = dict(
        u=ext(p.u, p.u[-1]), rho=ext(p.rho, 0.0), s=ext(p.s, p.s[-1]), dt=np.asarray(p.dt), norm=np.asarray(norm, float)
    )
    y = ext(p.y, 0.0)
    mask = ext(np.ones(T), 0.0)
    return {k: jnp.asarray(v) for k, v in data.items()}, jnp.asarray(y), jnp.asarray(mask)


def _residuals(theta, args):
    st, data, y, mask = args
    return mask * (model(theta, st, data) - y) / jnp.sqrt(jnp.sum(mask))


@eqx.filter_jit
def _solve(theta0, st, data, y, mask, *, solver, max_steps, rtol, atol):
    args = (st, data, y, mask)
    sol: optx.Solution = optx.least_squares(
        _residuals, least_squares_solver(solver, rtol, atol), theta0, args=args, max_steps=max_steps, throw=False
    )
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


def refine(
    p: Prepared, cfg, w, norm, *, solver="lm", max_steps: int = 100, rtol: float = 1e-6, atol: float = 1e-9
) -> Refined:
    """Refine a configuration fitted by `model.fit` jointly, by optimistix least squares.

    **Arguments:**

    - `p`: the record (normalised units, full rate).
    - `cfg`, `w`, `norm`: the configuration, its coefficients and the output map's
      normalisation, from `model.fit`.
    - `solver`: `"lm"` (Levenberg-Marquardt), `"gn"` (Gauss-Newton) or `"bfgs"`, or an optimistix
      least-squares solver or minimiser object (used as given).
    - `max_steps`, `rtol`, `atol`: the solver's step limit and tolerances (normalised units;
      the defaults are `fit_pi`'s, and `atol` bounds the mean squared error's last change, far
      below any measured record's noise).

    **Returns:** a `Refined`; `accepted` is False (and `theta` the start) when the solve did not
    lower the error of the exact model at the starting point, or gave a non-finite result; the
    caller then keeps the variable-projection fit.
    """
    check_solver(solver)
    st = structure(cfg)
    theta0 = initial_params(cfg, w, p.signed)
    if any(isinstance(e, OutputMapEffect) for e in chain(cfg)):
        theta0[CENTRE] = jnp.asarray(float(norm[0]))
    data, y, mask = data_of(p, norm)
    theta, result, steps, loss0, loss = _solve(
        theta0, st, data, y, mask, solver=solver, max_steps=max_steps, rtol=rtol, atol=atol
    )
    loss0, loss = float(loss0), float(loss)
    finite = np.isfinite(loss) and all(bool(jnp.all(jnp.isfinite(v))) for v in theta.values())
    accepted = bool(finite and loss < loss0)
    if not accepted:
        theta, loss = theta0, loss0
    new_cfg, _ = to_config(cfg, theta)
    return Refined(
        theta, st, new_cfg, result_name(result), int(steps), float(np.sqrt(loss0)), float(np.sqrt(loss)), accepted
    )


def predict(refined: Refined, p: Prepared, norm, *, transferable_only=False, history=None) -> np.ndarray:
    """The refined model's output on a record (normalised units, (T,)).

    **Arguments:** `refined`; `p`, a record in the identification record's units; `norm`, the
    output map's normalisation; `transferable_only`, as in `model`; `history`, turning
    points of an input history that sets the plays' initial states on this record (as the
    `initial_state` effect does), which implies `transferable_only` for the drift.

    **Returns:** the output (T,).
    """
    data, _, _ = data_of(p, norm, pad=False)
    theta, st = refined.theta, refined.structure
    if history is not None:
        theta = {**theta, "turns": jnp.asarray(history, data["u"].dtype)}
        st = tuple(sorted(_transferable(st) + (("initial_state", len(history)),), key=lambda a: EFFECT[a[0]].rank))
        transferable_only = False
    return np.asarray(_predict_jit(theta, st, data, transferable_only))


@eqx.filter_jit
def _predict_jit(theta, st, data, transferable_only):
    return model(theta, st, data, transferable_only=transferable_only)
