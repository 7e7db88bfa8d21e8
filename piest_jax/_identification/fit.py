"""Fitting a PI operator's thresholds, weights and offset to measured (u, y) data.

The model is y_t = Σ_j w_j H_{r_j}[u](t) + c, with the plays' states before the first sample either
given (by default every play starts at u_0, where all its stops are relaxed) or fitted. The
thresholds are kept ordered with r_1 = 0 by construction: r = (0, s_1, s_1 + s_2, ...), s_k =
softplus(θ_k) > 0. Weights are free, or w_j = softplus(θ_j) > 0 when `positive_weights`, which makes
every cumulative weight positive and so the fitted operator invertible.

The residuals are differentiated through the play scan and minimised by optimistix (Levenberg-
Marquardt by default). The play is piecewise linear in r and in u, so the residuals are piecewise
smooth and their Jacobian exists everywhere except at switching instants (a null set).

Scales: the fit runs in normalised units, u' = (u - u_mid)/u_half and y' = (y - y_mid)/y_half with
u_half, y_half half the peak-to-peak ranges, so one set of tolerances suits any data. The play is
affine-equivariant, H_r[a + b u] = a + b H_{r/b}[u] for b > 0, so the normalised model maps back to
user units exactly: r = u_half r', w = (y_half/u_half) w', states x = u_mid + u_half x'.

Starts: the weights of each start are the linear least-squares solution on a grid of thresholds;
several grids are solved at once by `vmap` (in batches on long records, to bound memory) and the
best final fit is kept. Levenberg-Marquardt fits of records longer than `LONG_RECORD` samples
never form the Jacobian: `normal_equations.py` accumulates JᵀJ and Jᵀr chunk by chunk.
`fit_pi` itself runs on the host: it validates the data and picks the best start in Python, around
one compiled solve. `fit_pi_core` is that solve with its normalisation and choice of start in JAX:
it runs under `jit` and `vmap`, and `grad` reaches the data through optimistix's implicit
derivative at the optimum.

Identifiability (paper Assumption 1): a play whose threshold is at or above half the input's
peak-to-peak range never traverses its loop, so its threshold is not determined by the data. Such
plays are returned in `flagged`; their thresholds are where the solver left them, not estimates.
More generally every parameter's standard error comes from the Jacobian of the residuals at the
solution (`covariance.py`), and a parameter the record does not determine (the Jacobian's rank, or
a standard error beyond half its scale) is named in `undetermined_names` and flags its play.
"""

import functools
from typing import Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jax import lax
from jaxtyping import Array, Bool, Float

from .. import _checks
from .._custom_types import Scalar, Signal, SignalLike, States, Thresholds, Weights
from .._memory import release_freed_memory
from .._models.composite import HysteresisModel
from .._models.creep import Creep, check_time_constants, decays, lag_states, lag_step
from .._operators.pi import PIOperator
from .._operators.play import play_step
from . import covariance as _cov
from . import time_constants
from .batches import map_in_batches
from .fit_data import Scales
from .fit_data import prepare as _prepare
from .solvers import SOLVERS as SOLVERS
from .solvers import check_solver, least_squares_solver, result_name
from .time_constants import initial_time_constants, lag_log_tau, lag_theta, shortest_time_constant
from .uncertainty import Uncertainty

# A solver name from `SOLVERS` or an optimistix solver object (`solvers.py`).
Solver = Literal["lm", "gn", "bfgs"] | optx.AbstractLeastSquaresSolver | optx.AbstractMinimiser


class PIFit(Uncertainty):
    """A fitted PI model y = Σ_j w_j H_{r_j}[u] + offset, in the data's units.

    **Fields:**

    - `thresholds` (n,): 0 = r_1 < r_2 < ... < r_n.
    - `weights` (n,), `offset` (scalar), `initial_states` (n,): the plays' states before sample 0.
    - `rmse`: root-mean-square residual on the fitted samples.
    - `result`: the optimistix result code of the chosen start (`optx.RESULTS`).
    - `flagged` (n,) bool: plays the record does not determine: not excited by the input
      (threshold >= half its peak-to-peak range), or with an undetermined threshold, weight or
      initial state (see `undetermined`).
    - `n_steps`: solver steps of the chosen start; `start_rmse` (starts,): every start's final RMSE.
    - `creep`: the fitted [`Creep`][] (time constants, weights, the lags' initial states), or
      None for a plain PI model.
    - `parameter_names`: the fitted parameters' names, e.g. `("thresholds[1]", ..., "weights[0]",
      ..., "offset", "creep.time_constants[0]", ...)`; r_1 = 0 is fixed and not among them.
    - `parameter_values` (p,): their values, in the data's units.
    - `covariance` (p, p), `std_errors` (p,): their estimated covariance and standard errors
      (`covariance_method`, see `fit_pi`); a parameter the record does not determine through the
      Jacobian's rank has an infinite standard error, and the covariance is then that of the
      determined combinations (finite). None when the fit was asked for no covariance.
    - `undetermined` (p,) bool: parameters the record does not determine (the Jacobian's
      numerical rank, or a standard error beyond half the parameter's scale).
    - `residual_std`: σ = sqrt(Σe²/(N − p)) over the N fitted samples, the residuals' standard
      deviation the covariance uses (and a new measurement's band adds, see
      [`prediction_band`][]); None with no covariance.
    - `held` (p,) bool: creep time constants the fit left on their bounds (the fastest at
      `min_time_constant`, another at √10 times the one before): the constraint, not the data,
      sets them, and the covariance treats them so (0 for the fastest, √10 times the previous
      one's for another); None with no covariance.
    """

    thresholds: Thresholds
    weights: Weights
    offset: Scalar
    initial_states: States
    rmse: Scalar
    result: optx.RESULTS
    flagged: Bool[Array, " plays"]
    n_steps: Array
    start_rmse: Float[Array, " starts"]
    creep: Creep | None = None
    held: Bool[Array, " params"] | None = None

    @property
    def held_names(self) -> tuple:
        """The creep time constants that sit on their bounds (see `covariance.on_bounds`)."""
        return _cov.flagged_names(self.parameter_names, self.held)

    @property
    def determined(self) -> bool:
        """True when the record determines every fitted parameter: none is undetermined and no
        play is flagged (the model-size choices keep only such fits)."""
        return not self.undetermined_names and not bool(np.any(np.asarray(self.flagged)))

    @property
    def n_plays(self) -> int:
        """The number of plays n."""
        return self.thresholds.shape[0]

    @property
    def result_name(self) -> str:
        """The solver result as a name such as `"successful"` or `"max_steps_reached"`."""
        return result_name(self.result)

    @property
    def n_lags(self) -> int:
        """The number of creep lags (0 for a plain PI model)."""
        return 0 if self.creep is None else self.creep.n_lags

    def operator(self) -> PIOperator:
        """The fitted PI operator without the offset and creep, as a [`PIOperator`][]."""
        return PIOperator(self.thresholds, self.weights, self.initial_states)

    def model(self) -> HysteresisModel:
        """The fitted model PI + creep + offset as a [`HysteresisModel`][]."""
        dt = None if self.creep is None else self.creep.dt
        return HysteresisModel(self.operator(), self.creep, self.offset, dt)

    def __call__(self, u: SignalLike, initial_states=None) -> Signal:
        """The model output operator(u) + creep(u) + offset for an input `u` (T,).

        The plays start from `initial_states` (scalar or (n,)), by default the fitted ones; a new
        record usually needs its own (e.g. 0 for a device relaxed at zero input). The creep's
        lags start from their fitted states, or at rest at u_0 when those were not fitted.
        """
        x0 = self.initial_states if initial_states is None else initial_states
        y = PIOperator(self.thresholds, self.weights, x0)(u) + self.offset
        return y if self.creep is None else y + self.creep(u)


def unexcited(u: SignalLike, thresholds) -> Bool[Array, " plays"]:
    """Which plays the input cannot excite: threshold >= half of u's peak-to-peak range.

    **Arguments:** `u` (T,), the input; `thresholds` (n,).

    **Returns:** (n,) booleans, True for a play whose threshold the data do not determine.
    """
    u = _checks.signal(u)
    r = jnp.atleast_1d(_checks.thresholds(thresholds))
    return r >= 0.5 * (jnp.max(u) - jnp.min(u))


def _softplus_inv(x):
    return x + jnp.log(-jnp.expm1(-x))


def _constrained(params, positive_weights, r_bound=None, active=None):
    """Thresholds and weights from the unconstrained parameters.

    `active` (n,) of 1s then 0s marks the plays in use when arrays are padded to a shared play
    count: the inactive plays get no increment and no weight, so they sit on the top active
    threshold and change nothing.
    """
    inc = jax.nn.softplus(params["increments"])
    if active is not None:
        inc = inc * active[1:]
    r = jnp.concatenate([jnp.zeros(1, inc.dtype), jnp.cumsum(inc)])
    if r_bound is not None:
        # r_j = r_bound S_j / (1 + S_n): still increasing from 0, and every r_j < r_bound.
        r = r_bound * r / (1.0 + r[-1])
    w = jax.nn.softplus(params["weights"]) if positive_weights else params["weights"]
    if active is not None:
        w = w * active
    return r, w


def _user_units(p, r, w, x0, s, n):
    """The first `n` plays' thresholds, weights, output offset and initial states in the data's
    units, from the normalised parameters `p`, their thresholds `r` and weights `w`
    (`_constrained`), the fixed states `x0` and the `Scales` `s`. `fit_pi` and `fit_pi_core` both
    map their fits back here, so the two report a solution the same way."""
    xn = p.get("initial_states", x0)
    r, w, xn = r[:n], w[:n], xn[:n]
    thresholds = r * s.u_half
    weights = w * s.y_half / s.u_half
    states = s.u_mid + s.u_half * xn
    # y = y_mid + y_half (Σ w' x' + Σ c' z' + c'), x' = (x - u_mid)/u_half, z' likewise: the plays'
    # share of u_mid moves to the offset here, a creep's is the caller's.
    offset = s.y_mid + s.y_half * p["offset"] - s.u_mid * jnp.sum(weights)
    return thresholds, weights, offset, states


def _lag_weights(params, positive_weights, lag_active=None):
    """The lags' weights c_k: c_k = softplus(θ_k) > 0 when `positive_weights`, else free in sign
    (see `fit_pi`'s `n_lags`)."""
    c = jax.nn.softplus(params["lag_weights"]) if positive_weights else params["lag_weights"]
    return c if lag_active is None else c * lag_active


def _predict(params, u, x0, positive_weights, r_bound=None, active=None, z0=None, lag_active=None, lag_base=None):
    """Normalised model output; x0 (and the lags' z0) are used unless the parameters carry fitted
    initial states. Time is in samples here (dt = 1)."""
    r, w = _constrained(params, positive_weights, r_bound, active)
    x0 = params.get("initial_states", x0)
    if "lag_theta" not in params:
        return run(u, r, w, params["offset"], x0)
    c = _lag_weights(params, positive_weights, lag_active)
    log_tau = lag_log_tau(params["lag_theta"], lag_base)
    return run(u, r, w, params["offset"], x0, log_tau, c, params.get("lag_states", z0))


def run(u, r, w, offset, x0, log_tau=None, c=None, z0=None, *, final=False):
    """The model's output in normalised units from its natural parameters: thresholds `r`,
    weights `w`, `offset`, play states `x0`, and optionally the lags' log time constants (in
    samples), weights `c` and states `z0`. The fit and its covariance both run the model here.
    With `final`, also the states after the last sample, `(x, z)`, to run on from there."""
    if log_tau is None:

        def step(x, ut):
            x = play_step(x, ut, r)
            return x, jnp.dot(w, x)

        x, y = lax.scan(step, x0, u)
        return (y + offset, (x, None)) if final else y + offset
    a = decays(log_tau, 1.0)

    # Plays and lags advance in one scan: on a CPU the per-sample overhead of a scan, not the
    # arithmetic, dominates, so a second scan would double the cost.
    def step_both(carry, ut):
        x, z = carry
        x, z = play_step(x, ut, r), lag_step(z, ut, a)
        return (x, z), jnp.dot(w, x) + jnp.dot(c, z)

    states, y = lax.scan(step_both, (x0, z0), u)
    return (y + offset, states) if final else y + offset


def padded_starts(r0s, x0, n_plays: int, pad_plays: int | None):
    """Starting thresholds (starts, n) and play states (n,) padded to `pad_plays` plays, and
    the (pad_plays,) mask of the active ones (None without padding).

    The padding repeats the top start threshold and state; those plays are inactive anyway
    (`_constrained` gives them no increment and no weight, `padding_residuals` holds them).
    """
    if pad_plays is None:
        return r0s, x0, None
    if not isinstance(pad_plays, (int, np.integer)) or pad_plays < n_plays:
        raise ValueError(f"`pad_plays` must be a whole number of at least n_plays={n_plays}, got {pad_plays!r}")
    # Even with no padding the mask is made, so that every padded fit has one structure. On the
    # host: these few small arrays would each compile a program per play count on the device.
    extra = int(pad_plays) - n_plays
    r0s, x0 = np.asarray(r0s), np.asarray(x0)
    r0s = np.concatenate([r0s, np.repeat(r0s[:, -1:], extra, axis=1)], axis=1)
    x0 = np.concatenate([x0, np.repeat(x0[-1:], extra)])
    return jnp.asarray(r0s), jnp.asarray(x0), jnp.asarray((np.arange(int(pad_plays)) < n_plays).astype(r0s.dtype))


def padding_residuals(params, x0, active) -> list:
    """One residual per inactive (padding) play parameter, zero where it starts.

    Inactive parameters do not reach the data residuals; these keep the Jacobian's columns
    independent (Gauss-Newton needs that) and leave the parameters where they are.
    """
    if active is None:
        return []
    off = 1.0 - active
    extra = [off[1:] * params["increments"], off * params["weights"]]
    if "initial_states" in params:
        extra.append(off * (params["initial_states"] - x0))
    return extra


def _residuals(params, args):
    """Masked residuals scaled so that their sum of squares is the mean squared error."""
    u, y, x0, mask, positive_weights, r_bound, active, z0, lag_active, lag_base = args
    count = jnp.maximum(jnp.sum(mask), 1.0)
    pred = _predict(params, u, x0, positive_weights, r_bound, active, z0, lag_active, lag_base)
    res = mask * (pred - y) / jnp.sqrt(count)
    extra = padding_residuals(params, x0, active)
    if lag_active is not None:
        off = 1.0 - lag_active
        extra += [off * params["lag_theta"], off * params["lag_weights"]]
        if "lag_states" in params:
            extra.append(off * (params["lag_states"] - z0))
    return jnp.concatenate([res, *extra]) if extra else res


def _grid(n, n_starts, dtype, key):
    """Starting thresholds (starts, n) in normalised units, where 1 is half the input range."""
    tops = jnp.linspace(1.0, 0.5, n_starts, dtype=dtype)
    base = jnp.arange(n, dtype=dtype) / n
    grids = tops[:, None] * base[None, :]
    if key is not None and n > 1:
        # Random increments with the same total spread, for starts beyond the first.
        g = jax.random.uniform(key, (n_starts, n - 1), dtype, 0.2, 1.0)
        g = jnp.concatenate([jnp.zeros((n_starts, 1), dtype), jnp.cumsum(g, axis=1)], axis=1)
        g = g / g[:, -1:] * tops[:, None] * (n - 1) / n
        grids = grids.at[1:].set(g[1:])
    return grids


# `_grid` as one compiled program per shape: eagerly its dozen operations would each compile one.
_start_grids = jax.jit(_grid, static_argnums=(0, 1, 2))


def _initial_params(
    r0,
    u,
    y,
    x0,
    mask,
    positive_weights,
    fit_initial_states,
    r_bound=None,
    active=None,
    z0=None,
    log_tau0=None,
    lag_active=None,
    lag_base=None,
    sol=None,
):
    """The starting parameters; `sol`, when given, is the weights' least-squares solution
    (play weights, lag weights, offset) already computed (the long-record path's, by chunks)."""
    n = r0.shape[0]
    # With padded arrays, n counts the active plays only (a traced number); the padding's
    # regressor columns are zero, so least squares gives them no weight.
    on = jnp.ones(n, r0.dtype) if active is None else active
    n_on = n if active is None else jnp.sum(active)
    top = n - 1 if active is None else jnp.sum(active).astype(int) - 1
    if sol is None:

        def step(x, ut):
            x = play_step(x, ut, r0)
            return x, x

        _, Hm = lax.scan(step, x0, u)
        cols = [Hm * on]
        if log_tau0 is not None:
            # The lags at their starting time constants are regressors too: their weights start
            # at the joint least-squares solution.
            k_on = jnp.ones_like(log_tau0) if lag_active is None else lag_active
            cols.append(lag_states(u, decays(log_tau0, 1.0), z0) * k_on)
        A = jnp.concatenate([*cols, jnp.ones_like(u)[:, None]], axis=1) * mask[:, None]
        sol = jnp.linalg.lstsq(A, y * mask)[0]
    w, c = sol[:n], sol[-1]
    if positive_weights:
        w = _softplus_inv(jnp.maximum(w, 1e-2 / n_on))
    if r_bound is None:
        inc = _softplus_inv(jnp.maximum(jnp.diff(r0), 1e-3))
    else:
        # Invert r = r_bound S / (1 + S_n): S = q (1 + S_n) with q = r / r_bound and S_n = q_n/(1-q_n).
        q = jnp.minimum(r0 / r_bound, 0.95 * (jnp.arange(n) + 1) / n_on)
        S = q * (1 + q[top] / (1 - q[top]))
        inc = _softplus_inv(jnp.maximum(jnp.diff(S), 1e-3))
    if active is not None:
        # Zero is where the inactive parameters' own residuals vanish (see `_residuals`).
        inc, w = inc * active[1:], w * active
    params = {"increments": inc, "weights": w, "offset": c}
    if fit_initial_states:
        params["initial_states"] = x0
    if log_tau0 is not None:
        cw = sol[n:-1]
        if positive_weights:
            cw = _softplus_inv(jnp.maximum(cw, 1e-2 / n_on))
        theta = lag_theta(log_tau0, lag_base)
        if lag_active is not None:
            cw, theta = cw * lag_active, theta * lag_active
        params["lag_theta"] = theta
        params["lag_weights"] = cw
        if fit_initial_states:
            params["lag_states"] = z0
    return params


@eqx.filter_jit
def _solve_starts(
    r0s,
    un,
    yn,
    x0,
    mask,
    r_bound,
    *,
    solver,
    positive_weights,
    fit_initial_states,
    max_steps,
    rtol,
    atol,
    batch=None,
    active=None,
    z0=None,
    log_tau0s=None,
    lag_active=None,
    lag_base=None,
):
    def one(r0, log_tau0, un, yn, x0, mask, r_bound, active, z0, lag_active, lag_base):
        args = (un, yn, x0, mask, positive_weights, r_bound, active, z0, lag_active, lag_base)
        p0 = _initial_params(
            r0,
            un,
            yn,
            x0,
            mask,
            positive_weights,
            fit_initial_states,
            r_bound,
            active,
            z0,
            log_tau0,
            lag_active,
            lag_base,
        )
        sol: optx.Solution = optx.least_squares(
            _residuals, least_squares_solver(solver, rtol, atol), p0, args=args, max_steps=max_steps, throw=False
        )
        res = _residuals(sol.value, args)
        loss = jnp.sum(res**2)
        loss = jnp.where(jnp.isfinite(loss), loss, jnp.inf)
        return sol.value, loss, sol.result, sol.stats["num_steps"]

    # Every data argument is batched along with the starts: reverse-mode differentiation of the
    # solver's implicit derivative under `vmap` fails when its arguments are shared (unbatched)
    # across the starts, while batched copies transpose cleanly. The copies cost starts x T.
    n = r0s.shape[0]
    data = (un, yn, x0, mask, r_bound, active, z0, lag_active, lag_base)
    data = jax.tree.map(lambda a: jnp.broadcast_to(a, (n,) + jnp.shape(a)), data)

    return map_in_batches(lambda xs: one(*xs), (r0s, log_tau0s, *data), batch)


# Above this many (padded) samples a Levenberg-Marquardt fit accumulates the normal equations
# chunk by chunk (`normal_equations.py`): memory stays at a few MB per start instead of about
# 1 kB per sample and start (256 MB for four starts at 2^16), and it runs 2-4x faster (measured
# from 2*10^3 to 10^5 samples, experiments/README.md). Below it the in-memory optimistix solve is
# kept: its memory is modest there, `_solve_starts` is differentiable in reverse mode (implicit
# differentiation at the optimum; `fit_pi_core` relies on it), and short-record fits stay exactly
# as they were.
LONG_RECORD = 2**16


# The in-memory solve takes starts_at_once x T near this many samples (see `fit_pi`).
STARTS_BUDGET = 2**20


def default_starts_at_once(T: int) -> int:
    """How many starts the in-memory solve takes at once for a (padded) record of T samples:
    starts x T near `STARTS_BUDGET`, and at least 1."""
    return max(1, STARTS_BUDGET // max(int(T), 1))


def fit_pi(
    u: SignalLike,
    y: SignalLike,
    n_plays: int,
    *,
    positive_weights: bool = True,
    fit_initial_states: bool = False,
    initial_states=None,
    solver: Solver = "lm",
    n_starts: int = 4,
    key=None,
    thresholds0=None,
    mask=None,
    max_threshold=None,
    max_steps: int = 100,
    rtol: float = 1e-6,
    atol: float = 1e-9,
    starts_at_once: int | None = None,
    pad_plays: int | None = None,
    n_lags: int = 0,
    dt: float = 1.0,
    time_constants0=None,
    pad_lags: int | None = None,
    min_time_constant: float | None = None,
    covariance: str | None = "newey-west",
) -> PIFit:
    """Fit thresholds, weights and an output offset (optionally initial states, optionally a creep
    of `n_lags` first-order lags) to one record, all parameters jointly.

    **Arguments:**

    - `u`, `y`: the measured input and output, (T,) each.
    - `n_plays`: the number of plays n (2n + 1 parameters, plus n with `fit_initial_states`).
    - `positive_weights`: keep every weight positive (the fitted operator is then invertible).
    - `fit_initial_states`: also fit the plays' states before the first sample.
    - `initial_states`: fixed states (scalar or (n,)) when they are not fitted; default u[0].
    - `solver`: `"lm"` (Levenberg-Marquardt), `"gn"` (Gauss-Newton) or `"bfgs"`, or an optimistix
      least-squares solver or minimiser object, used as given with its own tolerances.
    - `n_starts`: starting threshold grids, solved under `vmap` (see `starts_at_once`); the best
      is kept. On a Levenberg-Marquardt fit with more than 2^17 fitted samples the starts are
      compared on the stretch holding the first 2^16 fitted samples; the best is then fitted
      again on every sample (its final parameters and RMSE are from all samples), and the
      others' `start_rmse` is their RMSE on all samples as they stood.
    - `key`: a PRNG key; when given, starts after the first use random threshold spacings.
    - `thresholds0`: (n,) starting thresholds (r_1 = 0, increasing) instead of the grids.
    - `mask`: (T,) weights on the samples' residuals, 0 to hold a sample out (it still drives
      the plays' states).
    - `max_threshold`: an upper bound on every threshold (data units), kept by construction;
      e.g. a fraction of half the input range, where plays are barely excited (default none).
    - `max_steps`, `rtol`, `atol`: the solver's budget and tolerances (normalised units).
    - `starts_at_once`: how many starts the in-memory solve takes together under `vmap`;
      further ones follow batch by batch. Memory grows with `starts_at_once` x T (about 1 kB per
      sample and start in float64, mostly the residuals' Jacobian and its factorisation), so the
      default keeps `starts_at_once` x T near 2^20 samples. Levenberg-Marquardt fits of records
      longer than `LONG_RECORD` (2^16) samples do not hold the Jacobian at all: they accumulate
      the normal equations chunk by chunk, all starts at once, in memory that does not grow
      with T, and ignore this setting.
    - `pad_plays`: solve with arrays for this many plays (at least `n_plays`), the extra ones
      inactive, so that fits with different `n_plays` share one compilation (as
      [`select_plays`][] does on short records); the result is the same fit up to rounding (a
      BFGS fit stopped by `max_steps` far from its optimum can amplify that rounding), at the cost
      of `pad_plays` plays' work per step. Not with `thresholds0`.
    - `n_lags`: creep lags K (a [`Creep`][] of K first-order lags of u, time constants and weights
      fitted with everything else; 2K more parameters, 3K with `fit_initial_states`). With
      `positive_weights` the creep weights are positive too (the output keeps moving the way the
      input last moved), so the model's static map increases and its inverse is stable; without
      it they are free in sign (an output that relaxes back). The lags start at rest at u_0
      unless `fit_initial_states`.
    - `dt`: the sampling interval, the time unit of the creep's time constants.
    - `time_constants0`: (K,) starting time constants (default [`initial_time_constants`][]
      over the fitted stretch, each start at another place in the lags' bins); the starts after
      the first scale given ones by random factors in [1/2, 2] when `key` is given.
    - `pad_lags`: as `pad_plays`, for the lags (at least `n_lags`).
    - `min_time_constant`: the fastest creep time constant allowed (units of `dt`; default
      [`shortest_time_constant`][] of the fitted input: a lag much faster than the input's
      reversals trades its weight against the first play's and cannot be determined). The fitted
      time constants are kept ordered, at least this and each at least √10 times the one before
      (`docs/fitting.md`); starts outside those bounds begin on them.
    - `covariance`: how the parameters' covariance is estimated: `"newey-west"` (the default: a
      sandwich estimate that stays honest when the residuals are coloured, as a measured record's
      model error is), `"gauss-newton"` (σ²(JᵀJ)⁻¹, for white residuals) or None (none; the
      fit's `covariance`, `std_errors` and `undetermined` are then None). See
      `docs/covariance.md`.

    **Returns:** a [`PIFit`][] in the data's units. Raises `ValueError` for mismatched or
    non-finite data, an input with zero range, or more parameters than fitted samples.

    `fit_pi` runs on the host: it cannot be traced by `jax.jit` or `jax.vmap`, and `jax.grad`
    does not pass through it. [`fit_pi_core`][] is its fit (without creep or covariance) as a
    pure JAX function that can.
    """
    check_solver(solver)
    if covariance is not None and covariance not in _cov.METHODS:
        raise ValueError(f"unknown covariance {covariance!r}; choose one of {_cov.METHODS} or None")
    if n_starts < 1:
        raise ValueError(f"`n_starts` must be at least 1, got {n_starts}")
    if starts_at_once is not None and (not isinstance(starts_at_once, (int, np.integer)) or starts_at_once < 1):
        raise ValueError(f"`starts_at_once` must be a positive whole number, got {starts_at_once}")
    if not _checks.is_whole(max_steps) or max_steps < 1:
        raise ValueError(f"`max_steps` must be a positive whole number, got {max_steps!r}")
    max_steps = int(max_steps)  # optimistix takes Python integers only
    key = None if key is None else _checks.prng_key(key)
    per_lag = 3 if fit_initial_states else 2
    _check_lags(n_lags, pad_lags, dt)
    if min_time_constant is not None and not (np.isfinite(min_time_constant) and min_time_constant > 0):
        raise ValueError(f"`min_time_constant` must be positive and finite, got {min_time_constant!r}")
    un, yn, mask, s, x0, r_start = _prepare(
        u,
        y,
        n_plays,
        mask,
        thresholds0,
        initial_states,
        3 if fit_initial_states else 2,
        extra=per_lag * n_lags,
    )
    T = jnp.shape(u)[0]
    if r_start is None:
        r0s = _start_grids(n_plays, n_starts, un.dtype, key)
    else:
        r0s = r_start[None, :]
    if pad_plays is not None and r_start is not None:
        raise ValueError("`pad_plays` and `thresholds0` cannot be combined")
    r0s, x0, active = padded_starts(r0s, x0, n_plays, pad_plays)
    z0 = log_tau0s = lag_active = lag_base = None
    k_all = n_lags if pad_lags is None else int(pad_lags)
    if k_all > 0:
        used = np.flatnonzero(np.asarray(mask[:T]) > 0)
        shortest = (
            shortest_time_constant(np.asarray(un[:T]), 1.0, mask[:T])
            if min_time_constant is None
            else float(min_time_constant) / dt
        )
        lag_base = jnp.asarray(time_constants.lag_base(k_all, shortest), un.dtype)
        n_s = r0s.shape[0]
        if time_constants0 is None or n_lags == 0:
            tau0 = initial_time_constants(n_lags, 1.0, float(used[-1] - used[0] + 1), shortest, n_s)
        else:
            tau0 = np.asarray(check_time_constants(time_constants0, "time_constants0"), float)
            if tau0.shape != (n_lags,):
                raise ValueError(f"`time_constants0` has {tau0.size} entries for {n_lags} lags")
            tau0 = np.broadcast_to(np.sort(tau0) / dt, (n_s, n_lags))
            if key is not None and n_s > 1:
                # Starts after the first scale them by random factors in [1/2, 2].
                jitter = np.asarray(
                    jax.random.uniform(jax.random.fold_in(key, 1), tau0.shape, minval=-np.log(2.0), maxval=np.log(2.0))
                )
                tau0 = tau0 * np.exp(np.concatenate([np.zeros((1, n_lags)), jitter[1:]]))
                tau0 = np.sort(tau0, axis=1)
        # Padding lags (inactive) start above the active ones; their parameters are zeroed.
        pad = tau0[:, -1:] if n_lags else np.ones((n_s, 1))
        tau0 = np.concatenate([tau0, pad * time_constants.LAG_RATIO ** np.arange(1, k_all - n_lags + 1)], axis=1)
        log_tau0s = jnp.asarray(np.log(tau0), un.dtype)
        z0 = jnp.full(k_all, (jnp.asarray(u, un.dtype)[0] - s.u_mid) / s.u_half, un.dtype)
        if pad_lags is not None:
            lag_active = (jnp.arange(k_all) < n_lags).astype(un.dtype)
    r_bound = None
    if max_threshold is not None:
        if not float(max_threshold) > 0:
            raise ValueError(f"`max_threshold` must be positive, got {max_threshold}")
        r_bound = jnp.asarray(float(max_threshold), un.dtype) / s.u_half
        if r_start is not None and float(r_start[-1]) >= float(r_bound):
            raise ValueError("`thresholds0` must lie below `max_threshold`")
    common = dict(
        positive_weights=positive_weights,
        fit_initial_states=fit_initial_states,
        max_steps=max_steps,
        rtol=rtol,
        atol=atol,
        active=active,
        z0=z0,
        log_tau0s=log_tau0s,
        lag_active=lag_active,
        lag_base=lag_base,
    )
    long_record = un.shape[0] > LONG_RECORD
    if long_record:
        # What earlier steps freed (a candidate fit, the record's parsing) goes back to the
        # system first, so that the freed memory of one long fit does not add to the next.
        release_freed_memory()
    if isinstance(solver, str) and solver == "lm" and long_record:
        from .normal_equations import solve_starts

        params, loss, results, steps = solve_starts(r0s, un, yn, x0, mask, r_bound, **common)
    else:
        if starts_at_once is None:
            starts_at_once = default_starts_at_once(un.shape[0])
        params, loss, results, steps = _solve_starts(
            r0s,
            un,
            yn,
            x0,
            mask,
            r_bound,
            solver=solver,
            batch=min(int(starts_at_once), r0s.shape[0]),
            **common,
        )
    loss_np = np.asarray(loss)
    best = int(np.argmin(loss_np))
    if not np.isfinite(loss_np[best]):
        raise ValueError("every start of the fit produced non-finite residuals")
    p, r_all, w_all, (thresholds, weights, offset, states), lags, (rmse, start_rmse, result, n_steps) = _chosen(
        params, loss, results, steps, best, r_bound, active, x0, s, lag_base, dt, positive_weights, n_plays, n_lags
    )
    creep = None
    if n_lags > 0:
        tau, cw, zs = lags
        creep = Creep(tau, cw, dt, zs if fit_initial_states else None)
    fields = {}
    if covariance is not None:
        if n_lags > 0:
            # The covariance is taken in the natural parameters: the weights, not their softplus.
            p = p | {"lag_weights": _lag_weights(p, positive_weights)}
        fields = _cov.fit_fields(
            covariance,
            run,
            p,
            r_all,
            w_all,
            un,
            yn,
            mask,
            s,
            x0,
            z0,
            dt,
            lag_active,
            lag_base,
            fit_initial_states,
            n_plays,
            n_lags,
        )
    if long_record:
        release_freed_memory()
    flagged = np.asarray(thresholds) >= float(s.u_half)
    if fields:
        flagged = flagged | _cov.play_flags(fields["parameter_names"], fields["undetermined"], n_plays)
    return PIFit(
        thresholds=thresholds,
        weights=weights,
        offset=offset,
        initial_states=states,
        rmse=rmse,
        result=result,
        flagged=_checks.to_device(flagged),
        n_steps=n_steps,
        start_rmse=start_rmse,
        creep=creep,
        **fields,
    )


@functools.partial(jax.jit, static_argnums=(11, 12, 13))
def _chosen(
    params, loss, results, steps, best, r_bound, active, x0, s, lag_base, dt, positive_weights, n_plays, n_lags
):
    """The chosen start of `fit_pi` in the data's units, as one compiled program (eagerly, its
    few dozen small operations would each compile one for every play and lag count).

    **Returns:** `(p, r, w, (thresholds, weights, offset, states), lags, (rmse, start_rmse,
    result, n_steps))`: the start's normalised parameters with their thresholds and weights, the
    PI part as `_user_units` gives it, the lags' `(time constants, weights, states)` (None
    without lags) and the fit's summary.
    """
    p = jax.tree.map(lambda a: a[best], params)
    r, w = _constrained(p, positive_weights, r_bound, active)
    thresholds, weights, offset, states = _user_units(p, r, w, x0, s, n_plays)
    lags = None
    if n_lags > 0:
        # The lags' share of u_mid moves to the offset as the plays' does (`_user_units`).
        cw = _lag_weights(p, positive_weights)[:n_lags] * s.y_half / s.u_half
        offset = offset - s.u_mid * jnp.sum(cw)
        tau = jnp.exp(lag_log_tau(p["lag_theta"], lag_base)[:n_lags]) * dt
        zs = s.u_mid + s.u_half * p["lag_states"][:n_lags] if "lag_states" in p else None
        lags = (tau, cw, zs)
    summary = (
        jnp.sqrt(loss[best]) * s.y_half,
        jnp.sqrt(loss) * s.y_half,
        jax.tree.map(lambda a: a[best], results),
        steps[best],
    )
    return p, r, w, (thresholds, weights, offset, states), lags, summary


def _check_lags(n_lags, pad_lags, dt) -> None:
    if not isinstance(n_lags, (int, np.integer)) or n_lags < 0:
        raise ValueError(f"`n_lags` must be a whole number >= 0, got {n_lags!r}")
    if pad_lags is not None and (not isinstance(pad_lags, (int, np.integer)) or pad_lags < n_lags):
        raise ValueError(f"`pad_lags` must be a whole number of at least n_lags={n_lags}, got {pad_lags!r}")
    if not (isinstance(dt, (int, float, np.integer, np.floating)) and np.isfinite(dt) and dt > 0):
        raise ValueError(f"`dt` must be a positive finite number, got {dt!r}")


def uniform_pi(u: SignalLike, y: SignalLike, n_plays: int, *, initial_states=None, mask=None) -> PIFit:
    """The plain linear least-squares PI: n uniform thresholds on [0, half the input range).

    The baseline the gradient fit is compared with: only the weights and the offset are fitted.

    **Arguments:** `u`, `y` (T,); `n_plays`; `initial_states`, `mask` as in [`fit_pi`][].

    **Returns:** a [`PIFit`][] (its `result` is `successful`, `n_steps` 0).
    """
    un, yn, mask, s, x0, _ = _prepare(u, y, n_plays, mask, None, initial_states)
    r0 = jnp.arange(n_plays, dtype=un.dtype) / n_plays
    p = _initial_params(r0, un, yn, x0, mask, False, False)
    loss = jnp.sum(_residuals(p, (un, yn, x0, mask, False, None, None, None, None, None)) ** 2)
    weights = p["weights"] * s.y_half / s.u_half
    return PIFit(
        thresholds=r0 * s.u_half,
        weights=weights,
        offset=s.y_mid + s.y_half * p["offset"] - s.u_mid * jnp.sum(weights),
        initial_states=s.u_mid + s.u_half * x0,
        rmse=jnp.sqrt(loss) * s.y_half,
        # An equinox Enumeration's members are declared as strings and become items at run time.
        result=optx.RESULTS.successful,  # type: ignore[arg-type]
        flagged=jnp.zeros(n_plays, bool),
        n_steps=jnp.asarray(0),
        start_rmse=jnp.sqrt(loss)[None] * s.y_half,
    )


class PICoreFit(eqx.Module):
    """A PI model y = Σ_j w_j H_{r_j}[u] + offset fitted by [`fit_pi_core`][], in the data's units.

    Every field is an array (under `jax.vmap` over records, each gains a leading record axis).

    **Fields:**

    - `thresholds` (n,): 0 = r_1 < r_2 < ... < r_n.
    - `weights` (n,), `offset` (scalar), `initial_states` (n,): the plays' states before sample 0
      (the given ones, or the fitted ones with `fit_initial_states`).
    - `rmse`: root-mean-square residual on the fitted samples (weighted by `mask`).
    - `result`: the optimistix result code of the chosen start (`optx.RESULTS`).
    - `n_steps`: solver steps of the chosen start.
    - `start_rmse` (starts,): every start's final RMSE, inf for a start whose residuals were not
      finite.
    - `unexcited` (n,) bool: plays whose threshold is at or above half the input's peak-to-peak
      range, which the input never drives around their loop (their thresholds are where the
      solver left them; see [`unexcited`][piest_jax.unexcited]).
    """

    thresholds: Thresholds
    weights: Weights
    offset: Scalar
    initial_states: States
    rmse: Scalar
    result: optx.RESULTS
    n_steps: Array
    start_rmse: Float[Array, " starts"]
    unexcited: Bool[Array, " plays"]

    def operator(self) -> PIOperator:
        """The fitted PI operator without the offset, as a [`PIOperator`][] (of one record's fit)."""
        return PIOperator(self.thresholds, self.weights, self.initial_states)

    def __call__(self, u: SignalLike, initial_states=None) -> Signal:
        """The model output operator(u) + offset for an input `u` (T,), the plays starting from
        `initial_states` (scalar or (n,); by default the fitted ones)."""
        x0 = self.initial_states if initial_states is None else initial_states
        return PIOperator(self.thresholds, self.weights, x0)(u) + self.offset


def _refuse(x, checks):
    """`x`, after refusing it when any of `checks`, (bad, message) pairs, holds: a `ValueError`
    with the first one's message now when they are concrete (an eager call), else one
    `eqx.error_if` check, naming the first that holds, that every later value depends on (under
    `jit`, `vmap`, `grad`). One check, not one per problem, so that a traced call reports the same
    problem an eager one does, whatever order the compiled program runs in."""
    bad = jnp.stack([jnp.asarray(b) for b, _ in checks])
    messages = [m for _, m in checks]
    if _checks.is_concrete(bad):
        hits = np.flatnonzero(np.asarray(bad))
        if hits.size:
            raise ValueError(messages[hits[0]])
        return x
    return eqx.branched_error_if(x, jnp.any(bad), jnp.argmax(bad), messages)


def fit_pi_core(
    u: SignalLike,
    y: SignalLike,
    n_plays: int,
    *,
    positive_weights: bool = True,
    fit_initial_states: bool = False,
    initial_states=None,
    mask=None,
    solver: Solver = "lm",
    n_starts: int = 4,
    key=None,
    max_steps: int = 100,
    rtol: float = 1e-6,
    atol: float = 1e-9,
) -> PICoreFit:
    """[`fit_pi`][]'s fit of thresholds, weights and an output offset as a pure JAX function: it
    runs under `jax.jit`, under `jax.vmap` over records of one length, and `jax.grad` (or
    `jax.jacfwd`) of anything computed from its result reaches the data `y` and `u`.

    The fit is `fit_pi`'s, without a creep and without a covariance: the same normalisation of
    the data by their ranges, the same starting threshold grids and the same compiled multi-start
    solve, the best start picked by `jnp.argmin` and mapped back to the data's units the same way.
    The derivatives with respect to the data are those of the solver's optimum, by implicit
    differentiation (the implicit function theorem on the optimality condition), not through its
    iterations. They exist where the optimum is a regular minimum and a small change of the data
    keeps the input's extremes, the sample that tops each reversal and the best start where they
    are (the fit is piecewise smooth in `u`). The solver's tolerances bound their accuracy as they
    bound the fit's.

    How it relates to `fit_pi`: `fit_pi` runs on the host (NumPy checks, the best start picked
    in Python, the covariance), so it can be neither traced nor differentiated. With the options
    both take, on records of up to `LONG_RECORD` (2^16) samples, its solve is this one, except
    that `fit_pi` appends masked samples repeating the last input so that nearby record lengths
    share a compilation. Those samples move no play and add no residual, so both minimise the same
    function of the parameters from the same starts and their fits agree to rounding; should
    rounding make a converged fit stop a step sooner or later, or pick another of several starts
    that reached the same optimum, they agree to the solver's tolerance. Longer
    Levenberg-Marquardt fits in `fit_pi` accumulate the normal equations in bounded memory
    instead; this function keeps the residuals' Jacobian in memory at any length (about 1 kB per
    sample and start in float64).

    **Arguments:**

    - `u`, `y`: the measured input and output, (T,) each.
    - `n_plays`: the number of plays n (static).
    - `positive_weights`: keep every weight positive (static; the fitted operator is then
      invertible).
    - `fit_initial_states`: also fit the plays' states before the first sample (static).
    - `initial_states`: fixed states (scalar or (n,)) when they are not fitted, or where the fitted
      ones start; default u[0].
    - `mask`: (T,) weights on the samples' residuals, 0 to hold a sample out (it still drives the
      plays' states); default all ones.
    - `solver`: `"lm"` (Levenberg-Marquardt), `"gn"` (Gauss-Newton) or `"bfgs"`, or an optimistix
      least-squares solver or minimiser object (static).
    - `n_starts`: starting threshold grids, solved together under `vmap` (static); the best final
      fit is kept.
    - `key`: a PRNG key; when given, starts after the first use random threshold spacings.
    - `max_steps`, `rtol`, `atol`: the solver's budget and tolerances in normalised units
      (static).

    **Returns:** a [`PICoreFit`][] in the data's units. Raises `ValueError` for a static problem
    (a count below 1, mismatched shapes, more parameters than samples) when it is called or
    traced. A problem in the values (NaN or inf in the data, an input with zero range, fewer
    fitted samples than parameters under `mask`, no start with finite residuals) raises
    `ValueError` in an eager call and, under a transformation, stops the computation through
    `eqx.error_if` instead of returning NaN: an `EquinoxRuntimeError` naming the problem under
    `eqx.filter_jit`, a runtime error whose text names it under `jax.jit`.

    ```python
    fit = jax.jit(lambda u, y: pj.fit_pi_core(u, y, 3))(u, y)
    fits = jax.vmap(lambda u, y: pj.fit_pi_core(u, y, 3))(us, ys)  # records (B, T)
    g = jax.grad(lambda y: pj.fit_pi_core(u, y, 3).thresholds[-1])(y)  # d r_n / d y
    ```
    """
    check_solver(solver)
    for name, count in (("n_plays", n_plays), ("n_starts", n_starts), ("max_steps", max_steps)):
        if not _checks.is_whole(count) or count < 1:
            raise ValueError(f"`{name}` must be a positive whole number, got {count!r}")
    for name, tol in (("rtol", rtol), ("atol", atol)):
        if not (isinstance(tol, int | float | np.integer | np.floating) and np.isfinite(tol) and tol >= 0):
            raise ValueError(f"`{name}` must be a non-negative finite number, got {tol!r}")
    for name, flag in (("positive_weights", positive_weights), ("fit_initial_states", fit_initial_states)):
        if not isinstance(flag, bool | np.bool_):
            raise ValueError(f"`{name}` must be True or False (it is static), got {flag!r}")
    n_plays, n_starts = int(n_plays), int(n_starts)
    u = _checks.signal(u, "u")
    y = _checks.signal(y, "y")
    if u.shape != y.shape:
        raise ValueError(f"`u` has {u.shape[0]} samples but `y` has {y.shape[0]}")
    dtype = jnp.result_type(u, y)
    u, y = u.astype(dtype), y.astype(dtype)
    T = u.shape[0]
    n_params = (3 if fit_initial_states else 2) * n_plays + 1
    if n_params > T:
        raise ValueError(
            f"{n_plays} plays need {n_params} parameters but the record has only {T} samples; "
            "use fewer plays or a longer record"
        )
    if mask is None:
        mask = jnp.ones_like(u)
    else:
        mask = jnp.asarray(mask, dtype)
        if mask.shape != u.shape:
            raise ValueError(f"`mask` has shape {mask.shape}, expected {u.shape}")
    if initial_states is None:
        x0 = jnp.broadcast_to(u[0], (n_plays,))
    else:
        x0 = jnp.broadcast_to(_checks.per_play(initial_states, n_plays, "initial_states").astype(dtype), (n_plays,))
    key = None if key is None else _checks.prng_key(key)

    n_fit = jnp.sum(mask > 0)
    u_lo, u_hi = jnp.min(u), jnp.max(u)
    # As in `fit_pi`: residuals in the data's units are squared and summed for the RMSE.
    limit = jnp.sqrt(jnp.finfo(dtype).max / jnp.maximum(n_fit, 1).astype(dtype))
    name = jnp.dtype(dtype).name
    u, y, mask, x0 = _refuse(
        (u, y, mask, x0),
        [
            (~jnp.all(jnp.isfinite(u)), "`u` contains NaN or inf"),
            (~jnp.all(jnp.isfinite(y)), "`y` contains NaN or inf"),
            (~jnp.all(jnp.isfinite(mask)), "`mask` contains NaN or inf"),
            (~jnp.all(jnp.isfinite(x0)), "`initial_states` contains NaN or inf"),
            (~jnp.isfinite(u_hi - u_lo), f"the input's range overflows {name}; rescale `u`"),
            (~(u_hi > u_lo), "the input has zero range (a constant): it excites no play"),
            (
                jnp.max(jnp.abs(y)) >= limit,
                f"`y` has values out of the range the fit can square and sum in {name}; rescale it",
            ),
            (n_fit < n_params, f"{n_plays} plays need {n_params} parameters but fewer samples are fitted (`mask`)"),
        ],
    )
    y_lo, y_hi = jnp.min(y), jnp.max(y)
    s = Scales(
        u_mid=0.5 * (u_lo + u_hi),
        u_half=0.5 * (u_hi - u_lo),
        y_mid=0.5 * (y_lo + y_hi),
        y_half=jnp.where(y_hi > y_lo, 0.5 * (y_hi - y_lo), jnp.ones((), dtype)),
    )
    un, yn, x0 = (u - s.u_mid) / s.u_half, (y - s.y_mid) / s.y_half, (x0 - s.u_mid) / s.u_half

    params, loss, results, steps = _solve_starts(
        _grid(n_plays, n_starts, dtype, key),
        un,
        yn,
        x0,
        mask,
        None,
        solver=solver,
        positive_weights=positive_weights,
        fit_initial_states=fit_initial_states,
        max_steps=int(max_steps),
        rtol=rtol,
        atol=atol,
        batch=min(default_starts_at_once(T), n_starts),
    )
    best = jnp.argmin(loss)
    p = jax.tree.map(lambda a: a[best], params)
    p, loss = _refuse((p, loss), [(~jnp.isfinite(loss[best]), "every start of the fit produced non-finite residuals")])
    r, w = _constrained(p, positive_weights)
    thresholds, weights, offset, states = _user_units(p, r, w, x0, s, n_plays)
    return PICoreFit(
        thresholds=thresholds,
        weights=weights,
        offset=offset,
        initial_states=states,
        rmse=jnp.sqrt(loss[best]) * s.y_half,
        result=jax.tree.map(lambda a: a[best], results),
        n_steps=steps[best],
        start_rmse=jnp.sqrt(loss) * s.y_half,
        unexcited=thresholds >= s.u_half,
    )
