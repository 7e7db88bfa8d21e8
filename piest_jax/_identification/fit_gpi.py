"""Fitting a generalized PI model y = g(P[u]) to measured (u, y): everything jointly.

The thresholds, the (positive) weights, the output function's amplitudes, centres and scales and
the offset are fitted together by optimistix (Levenberg-Marquardt by default) through the play
scan, in the normalised units of `fit_pi` (`fit_data.prepare`: input and output each spanning
[-1, 1]), with `fit_pi`'s threshold parameterisation (r_1 = 0, softplus increments, an optional
upper bound), its starting threshold grids and its model runner (`fit.run`), so the PI part is
the same model in both fits.

**The scale.** (w, c, s) -> (λw, λc, λs) leaves the model unchanged, so one scale is fixed: s_1
= 1 (the first term's scale). Every other parameter is then determined by a record that excites
the plays and reaches into the saturation.

**Starts.** Each start takes its thresholds from `fit_pi`'s grids and its weights and offset from
the plain PI's linear least squares at those thresholds (`fit._initial_params`); the output
function starts close to the identity over the data: amplitudes summing to 1.5 (the data span
[-1, 1], so the start saturates mildly), centres spread over [-1/2, 1/2], scales 1, and the PI's
weights shrunk by the output function's slope at 0 so that the start reproduces the PI fit near
the middle of the range.

Back in the data's units: r = u_half r', w = w'/u_half (the PI output keeps the normalised
output's unit), c = c' + u_mid Σ w, s = s', a = y_half a', offset = y_mid + y_half offset'.
"""

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from .._custom_types import Scalar, Signal, SignalLike
from .._models.gpi import GeneralizedPI, output_function
from .._operators.pi import PIOperator
from . import covariance as _cov
from . import gpi_covariance
from .batches import map_in_batches
from .fit import (
    Solver,
    _constrained,
    _initial_params,
    _softplus_inv,
    _start_grids,
    default_starts_at_once,
    padded_starts,
    padding_residuals,
    run,
)
from .fit_data import prepare
from .solvers import check_solver, least_squares_solver, result_name
from .uncertainty import Uncertainty

START_AMPLITUDE = 1.5  # the start's Σ a_k in normalised output units (the data span [-1, 1])


class GPIFit(Uncertainty):
    """The result of [`fit_gpi`][piest_jax.fit_gpi].

    **Fields:**

    - `model`: the fitted [`GeneralizedPI`][piest_jax.GeneralizedPI], in the data's units, with
      s_1 = 1.
    - `rmse`: root-mean-square residual on the fitted samples.
    - `result`: the optimistix result code of the chosen start; `n_steps` its solver steps.
    - `start_rmse` (starts,): every start's final RMSE.
    - `parameter_names`, `parameter_values`, `covariance`, `std_errors`, `undetermined`,
      `covariance_method`, `residual_std`: as [`PIFit`][]'s, for the generalized model's
      parameters (`"thresholds[1]"`, ..., `"weights[0]"`, ..., `"output.amplitudes[0]"`, ...,
      `"output.centres[0]"`, ..., `"output.scales[1]"`, ..., `"offset"`, and
      `"initial_states[1]"`, ... when fitted; s_1 = 1 is fixed and not among them); None when
      the fit was asked for no covariance.
    """

    model: GeneralizedPI
    rmse: Scalar
    result: optx.RESULTS
    n_steps: jax.Array
    start_rmse: jax.Array

    @property
    def determined(self) -> bool:
        """True when the record determines every fitted parameter."""
        return not self.undetermined_names

    @property
    def result_name(self) -> str:
        """The solver result as a name such as `"successful"` or `"max_steps_reached"`."""
        return result_name(self.result)

    @property
    def n_plays(self) -> int:
        """The number of plays n."""
        return self.model.n_plays

    def __call__(self, u: SignalLike, initial_states=None) -> Signal:
        """The fitted model's output for `u` (T,), its plays started from `initial_states`
        (scalar or (n,); default the fitted ones)."""
        m = self.model if initial_states is None else self.model.with_initial_states(initial_states)
        return m(u)


def _unpack(params, r_bound, active=None):
    r, w = _constrained(params, True, r_bound, active)
    # s_1 = 1; with one term there is no other scale (and no empty parameter array).
    log_s = jnp.zeros(1, params["centres"].dtype)
    if "log_scales" in params:
        log_s = jnp.concatenate([log_s, params["log_scales"]])
    return r, w, params["log_amplitudes"], params["centres"], log_s


def _predict(params, u, x0, r_bound, active=None):
    r, w, log_a, c, log_s = _unpack(params, r_bound, active)
    v = run(u, r, w, 0.0, params.get("initial_states", x0))
    return output_function(v, log_a, c, log_s, params["offset"])


def _residuals(params, args):
    u, y, x0, mask, r_bound, active = args
    count = jnp.maximum(jnp.sum(mask), 1.0)
    res = mask * (_predict(params, u, x0, r_bound, active) - y) / jnp.sqrt(count)
    extra = padding_residuals(params, x0, active)
    return jnp.concatenate([res, *extra]) if extra else res


def _start(r0, u, y, x0, mask, r_bound, active, n_terms, fit_initial_states):
    p = _initial_params(r0, u, y, x0, mask, True, fit_initial_states, r_bound, active)
    dtype = u.dtype
    log_a = jnp.full(n_terms, jnp.log(START_AMPLITUDE / n_terms), dtype)
    c = 0.5 * jnp.linspace(-1.0, 1.0, n_terms, dtype=dtype) if n_terms > 1 else jnp.zeros(1, dtype)
    slope = jnp.sum(jnp.exp(log_a) / jnp.cosh(c) ** 2)  # g'(0) with unit scales
    w = _softplus_inv(jax.nn.softplus(p["weights"]) / slope)
    # Padding plays' weights stay at zero, where their own residuals vanish.
    p["weights"] = w if active is None else w * active
    p["log_amplitudes"] = log_a
    p["centres"] = c
    if n_terms > 1:
        p["log_scales"] = jnp.zeros(n_terms - 1, dtype)
    return p


@eqx.filter_jit
def _solve_starts(
    r0s, u, y, x0, mask, r_bound, active, *, n_terms, fit_initial_states, solver, max_steps, rtol, atol, batch
):
    args = (u, y, x0, mask, r_bound, active)

    def one(r0):
        p0 = _start(r0, u, y, x0, mask, r_bound, active, n_terms, fit_initial_states)
        sol: optx.Solution = optx.least_squares(
            _residuals, least_squares_solver(solver, rtol, atol), p0, args=args, max_steps=max_steps, throw=False
        )
        loss = jnp.sum(_residuals(sol.value, args) ** 2)
        loss = jnp.where(jnp.isfinite(loss), loss, jnp.inf)
        return sol.value, loss, sol.result, sol.stats["num_steps"]

    return map_in_batches(one, r0s, batch)


def fit_gpi(
    u: SignalLike,
    y: SignalLike,
    n_plays: int,
    *,
    n_terms: int = 2,
    fit_initial_states: bool = False,
    initial_states=None,
    solver: Solver = "lm",
    n_starts: int = 4,
    key=None,
    mask=None,
    max_threshold=None,
    max_steps: int = 200,
    rtol: float = 1e-6,
    atol: float = 1e-9,
    starts_at_once: int | None = None,
    pad_plays: int | None = None,
    covariance: str | None = "newey-west",
) -> GPIFit:
    """Fit a generalized PI model y = g(P[u]) (thresholds, positive weights, the output
    function's amplitudes, centres and scales, and the offset) to one record, jointly.

    **Arguments:**

    - `u`, `y`: the measured input and output, (T,) each.
    - `n_plays`: the number of plays n.
    - `n_terms`: the output function's tanh terms K (default 2: one term fixes the knee's shape,
      a second lets the knee and the approach to saturation differ; see
      [`GeneralizedPI`][piest_jax.GeneralizedPI]). 2n + 3K parameters in all (s_1 = 1 fixed).
    - `fit_initial_states`: also fit the plays' states before the first sample.
    - `initial_states`: fixed states (scalar or (n,)) when they are not fitted; default u[0].
    - `solver`: `"lm"`, `"gn"`, `"bfgs"` or an optimistix solver object, as for [`fit_pi`][].
    - `n_starts`: starting threshold grids (those of [`fit_pi`][]); the best fit is kept.
    - `key`: a PRNG key; when given, starts after the first use random threshold spacings.
    - `mask`: (T,) weights on the samples' residuals, 0 to hold a sample out (it still drives
      the plays).
    - `max_threshold`: an upper bound on every threshold (data units), kept by construction.
    - `max_steps`, `rtol`, `atol`: the solver's budget and tolerances (normalised units).
    - `starts_at_once`: starts solved together under `vmap` (memory grows with it times T);
      default as for [`fit_pi`][].
    - `pad_plays`: solve with arrays for this many plays (at least `n_plays`), the extra ones
      inactive, so that fits with different `n_plays` share one compilation, as for
      [`fit_pi`][]: the same fit up to rounding, at the cost of `pad_plays` plays' work per step.
    - `covariance`: `"newey-west"` (default), `"gauss-newton"` or None, as for [`fit_pi`][]
      (`gpi_covariance.py` names the parameters and their scales).

    **Returns:** a [`GPIFit`][piest_jax.GPIFit] in the data's units. Raises `ValueError` for
    mismatched or non-finite data, an input with zero range, or more parameters than fitted
    samples.
    """
    check_solver(solver)
    if covariance is not None and covariance not in _cov.METHODS:
        raise ValueError(f"unknown covariance {covariance!r}; choose one of {_cov.METHODS} or None")
    if not isinstance(n_terms, (int, np.integer)) or n_terms < 1:
        raise ValueError(f"`n_terms` must be a positive whole number, got {n_terms!r}")
    if not isinstance(n_starts, (int, np.integer)) or n_starts < 1:
        raise ValueError(f"`n_starts` must be at least 1, got {n_starts!r}")
    if not isinstance(max_steps, (int, np.integer)) or max_steps < 1:
        raise ValueError(f"`max_steps` must be a positive whole number, got {max_steps!r}")
    if starts_at_once is not None and (not isinstance(starts_at_once, (int, np.integer)) or starts_at_once < 1):
        raise ValueError(f"`starts_at_once` must be a positive whole number, got {starts_at_once}")
    n_terms = int(n_terms)
    un, yn, mask, s, x0, _ = prepare(
        u, y, n_plays, mask, None, initial_states, 3 if fit_initial_states else 2, extra=3 * n_terms - 1
    )
    r_bound = None
    if max_threshold is not None:
        if not float(max_threshold) > 0:
            raise ValueError(f"`max_threshold` must be positive, got {max_threshold}")
        r_bound = jnp.asarray(float(max_threshold), un.dtype) / s.u_half
    r0s, x0, active = padded_starts(_start_grids(n_plays, n_starts, un.dtype, key), x0, n_plays, pad_plays)
    batch = default_starts_at_once(un.shape[0]) if starts_at_once is None else int(starts_at_once)
    params, loss, results, steps = _solve_starts(
        r0s,
        un,
        yn,
        x0,
        mask,
        r_bound,
        active,
        n_terms=n_terms,
        fit_initial_states=fit_initial_states,
        solver=solver,
        max_steps=int(max_steps),
        rtol=rtol,
        atol=atol,
        batch=max(1, min(batch, n_starts)),
    )
    loss_np = np.asarray(loss)
    best = int(np.argmin(loss_np))
    if not np.isfinite(loss_np[best]):
        raise ValueError("every start of the fit produced non-finite residuals")
    thresholds, weights, states, amplitudes, centres, scales, offset, rmse, start_rmse, result, n_steps = _chosen(
        params, loss, results, steps, best, r_bound, active, x0, s, n_plays
    )
    model = GeneralizedPI(PIOperator(thresholds, weights, states), amplitudes, centres, scales, offset)
    fields = {}
    if covariance is not None:
        T = jnp.shape(u)[0]
        fields = gpi_covariance.fields(
            covariance,
            model,
            u,
            y,
            np.asarray(mask)[:T],
            fit_initial_states,
            None if pad_plays is None else int(pad_plays),
        )
    return GPIFit(model=model, rmse=rmse, result=result, n_steps=n_steps, start_rmse=start_rmse, **fields)


@functools.partial(jax.jit, static_argnums=(9,))
def _chosen(params, loss, results, steps, best, r_bound, active, x0, s, n_plays):
    """The chosen start of `fit_gpi` in the data's units, as one compiled program (eagerly, its
    small operations would each compile one for every play count).

    **Returns:** the PI part's thresholds, weights and states, the output function's amplitudes,
    centres and scales, the offset, and the fit's RMSE, every start's RMSE, result and steps.
    """
    p = jax.tree.map(lambda a: a[best], params)
    r, w, log_a, c, log_s = _unpack(p, r_bound, active)
    r, w, x = r[:n_plays], w[:n_plays] / s.u_half, p.get("initial_states", x0)[:n_plays]
    return (
        r * s.u_half,
        w,
        s.u_mid + s.u_half * x,
        s.y_half * jnp.exp(log_a),
        c + s.u_mid * jnp.sum(w),
        jnp.exp(log_s),
        s.y_mid + s.y_half * p["offset"],
        jnp.sqrt(loss[best]) * s.y_half,
        jnp.sqrt(loss) * s.y_half,
        jax.tree.map(lambda a: a[best], results),
        steps[best],
    )
