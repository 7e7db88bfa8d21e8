"""Levenberg-Marquardt on normal equations accumulated chunk by chunk: the fit of long records.

The in-memory fit (`fit.py`) hands optimistix the residual vector r (T,) and lets it form the
Jacobian J (T, p): memory grows like starts x T x p, so about a million samples is the limit.
Here the record is cut into chunks of `CHUNK` samples and a `lax.scan` over the chunks
accumulates

    JᵀJ (p, p),    Jᵀr (p,),    rᵀr,

carrying the plays' states (and the creep lags') from one chunk to the next together with their
forward-mode sensitivities d(state)/dθ (p, n): inside a chunk, `jax.jvp` of the chunk's
residuals, vmapped over the p basis directions and started from the carried sensitivities, gives
that chunk's rows of J exactly (the chain rule across the chunk boundary). Besides a few copies
of the record itself, peak memory is O(CHUNK x p) per start, whatever T is, and the time of a
pass is linear in T.

The solver is a compact Levenberg-Marquardt on the p x p system that takes the same steps as
`optx.LevenbergMarquardt` on the full residuals, up to rounding (it solves the damped normal
equations by an eigendecomposition where optimistix factors [J; √λ I] by QR): the same damping (λ = 1/step size, the
classical trust region's accept/grow/shrink rule with cutoffs 0.01/0.99 and factors 3.5/0.25)
and the same convergence test (the max-norm Cauchy test on the parameters and on every
residual, rtol/atol as in `fit_pi`); the residual test needs the previous accepted point's
residuals, which the same pass recomputes without tangents. It is written out here rather than
passed to optimistix because optimistix's least-squares solvers take a residual function and
linearise it themselves: a p-row "compressed" residual with the right JᵀJ would give the same
steps but change the per-residual convergence test, and a lineax operator for the full J would
need a pass over the record per matrix-vector product.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jax import lax
from jax.flatten_util import ravel_pytree

from .._bounded_jit import bounded_jit
from .._models.creep import decays, lag_step
from .._operators.play import play_step
from .._progress import bar as _bar
from . import fit as _fit
from .covariance import chunked as chunked
from .time_constants import lag_log_tau

# Samples per chunk: it divides every padded length from 2^15 samples on (see
# `fit_data.pad_count`), and J's rows for one chunk, p x CHUNK, stay small.
CHUNK = 4096
# Fitted samples on which the starts of a long record are compared (see `solve_starts`).
SCOUT = 2**16
# Play steps per scan iteration inside a chunk: fewer loop iterations, the same arithmetic.
UNROLL = 8


class Settings(eqx.Module):
    """What the residuals depend on besides the parameters (static flags, fixed arrays)."""

    positive_weights: bool = eqx.field(static=True)
    rtol: float = eqx.field(static=True)
    atol: float = eqx.field(static=True)
    r_bound: jax.Array | None
    active: jax.Array | None
    lag_active: jax.Array | None
    x0: jax.Array
    z0: jax.Array | None
    lag_base: jax.Array | None = None


def _start_states(params, st: Settings):
    """The plays' (and lags') states before the first sample: fitted, or the fixed ones."""
    x = params.get("initial_states", st.x0)
    z = params.get("lag_states", st.z0) if "lag_theta" in params else None
    return x, z


def _chunk_residuals(params, states, data, scale, st: Settings):
    """Residuals of one chunk (chunk,) and the states after it, from the states before it."""
    u, y, m = data
    r, w = _fit._constrained(params, st.positive_weights, st.r_bound, st.active)
    x, z = states
    if z is None:

        def step(x, ut):
            x = play_step(x, ut, r)
            return x, jnp.dot(w, x)

        x, pred = lax.scan(step, x, u, unroll=UNROLL)
    else:
        a = decays(lag_log_tau(params["lag_theta"], st.lag_base), 1.0)
        c = _fit._lag_weights(params, st.positive_weights, st.lag_active)

        def step(carry, ut):
            x, z = carry
            x, z = play_step(x, ut, r), lag_step(z, ut, a)
            return (x, z), jnp.dot(w, x) + jnp.dot(c, z)

        (x, z), pred = lax.scan(step, (x, z), u, unroll=UNROLL)
    return m * (pred + params["offset"] - y) * scale, (x, z)


def _extra_residuals(params, st: Settings):
    """The residuals that hold padding (inactive) parameters in place: those of an empty record."""
    empty = jnp.zeros((0,), st.x0.dtype)
    return _fit._residuals(
        params,
        (empty, empty, st.x0, empty, st.positive_weights, st.r_bound, st.active, st.z0, st.lag_active, st.lag_base),
    )


def normal_equations(theta, unravel, data, st: Settings, theta_old=None, first=None):
    """Accumulate JᵀJ, Jᵀr and rᵀr of the fit's residuals at `theta` over the record's chunks.

    **Arguments:**

    - `theta` (p,): the parameters, flattened; `unravel` maps them back to the parameter dict.
    - `data`: `(u, y, mask)`, each (chunks, CHUNK), in normalised units (see [`chunked`][]).
    - `st`: the [`Settings`][].
    - `theta_old` (p,), `first`: when given, also the largest per-residual change from the
      residuals at `theta_old` (taken as zero when `first`), scaled by `atol + rtol |r|`.

    **Returns:** `(JtJ, Jtr, loss, change)`: (p, p), (p,), rᵀr, and the scaled change (0 when
    `theta_old` is None).
    """
    u, y, m = data
    p = theta.shape[0]
    scale = 1.0 / jnp.sqrt(jnp.maximum(jnp.sum(m), 1.0))
    params = unravel(theta)

    def start(th):
        return _start_states(unravel(th), st)

    s0 = start(theta)
    # d(start states)/dθ as (p, n) rows: one per basis direction of θ.
    ds0 = jax.tree.map(lambda a: jnp.moveaxis(a, -1, 0), jax.jacfwd(start)(theta))
    eye = jnp.eye(p, dtype=theta.dtype)
    old = theta_old is not None
    s_old = start(theta_old) if old else None
    fresh = jnp.asarray(0.0 if first is None else first, theta.dtype)

    def body(carry, chunk):
        s, ds, s_old, JtJ, Jtr, loss, change = carry

        def f(th, s):
            return _chunk_residuals(unravel(th), s, chunk, scale, st)

        def tangent(t, d):
            return jax.jvp(f, (theta, s), (t, d))

        (res, s_new), (J, ds_new) = jax.vmap(tangent, out_axes=(None, 0))(eye, ds)
        JtJ = JtJ + J @ J.T
        Jtr = Jtr + J @ res
        loss = loss + res @ res
        if old:
            res_old, s_old = _chunk_residuals(unravel(theta_old), s_old, chunk, scale, st)
            diff = jnp.abs(res - (1.0 - fresh) * res_old) / (st.atol + st.rtol * jnp.abs(res))
            change = jnp.maximum(change, jnp.max(diff))
        return (s_new, ds_new, s_old, JtJ, Jtr, loss, change), None

    zero = jnp.zeros((), theta.dtype)
    init = (s0, ds0, s_old, jnp.zeros((p, p), theta.dtype), jnp.zeros(p, theta.dtype), zero, zero)
    (_, _, _, JtJ, Jtr, loss, change), _ = lax.scan(body, init, (u, y, m))
    # The padding parameters' own residuals depend on θ alone: their rows are added directly.
    e = _extra_residuals(params, st)
    if e.shape[0]:
        Je = jax.jacfwd(lambda th: _extra_residuals(unravel(th), st))(theta)
        JtJ, Jtr, loss = JtJ + Je.T @ Je, Jtr + Je.T @ e, loss + e @ e
        if old:
            e_old = _extra_residuals(unravel(theta_old), st)
            diff = jnp.abs(e - (1.0 - fresh) * e_old) / (st.atol + st.rtol * jnp.abs(e))
            change = jnp.maximum(change, jnp.max(diff))
    return JtJ, Jtr, loss, change


def start_regression(r0, log_tau0, data, st: Settings):
    """The starting weights' least squares (plays at `r0`, lags at `log_tau0`, offset), from
    normal equations accumulated over the chunks.

    **Returns:** the solution (n + K + 1,): play weights, lag weights, offset.
    """
    u, y, m = data
    on = jnp.ones_like(r0) if st.active is None else st.active
    a = None if log_tau0 is None else decays(log_tau0, 1.0)
    k_on = None
    if log_tau0 is not None:
        k_on = jnp.ones_like(log_tau0) if st.lag_active is None else st.lag_active

    def body(carry, chunk):
        (x, z), AtA, Aty = carry
        uc, yc, mc = chunk

        def step(s, ut):
            x, z = s
            x = play_step(x, ut, r0)
            if z is None:
                return (x, z), x * on
            assert a is not None and k_on is not None  # lags run only with log_tau0
            z = lag_step(z, ut, a)
            return (x, z), jnp.concatenate([x * on, z * k_on])

        s, cols = lax.scan(step, (x, z), uc, unroll=UNROLL)
        A = jnp.concatenate([cols, jnp.ones_like(uc)[:, None]], axis=1) * mc[:, None]
        return (s, AtA + A.T @ A, Aty + A.T @ (yc * mc)), None

    q = r0.shape[0] + (0 if log_tau0 is None else log_tau0.shape[0]) + 1
    init = ((st.x0, st.z0 if log_tau0 is not None else None), jnp.zeros((q, q), r0.dtype), jnp.zeros(q, r0.dtype))
    (_, AtA, Aty), _ = lax.scan(body, init, (u, y, m))
    # Scaled to unit diagonal so that the cut-off for a rank-deficient (padded) system is relative.
    d = jnp.sqrt(jnp.where(jnp.diag(AtA) > 0, jnp.diag(AtA), 1.0))
    sol = jnp.linalg.lstsq(AtA / d[:, None] / d[None, :], Aty / d)[0]
    return sol / d


class _LMState(eqx.Module):
    y: jax.Array
    y_eval: jax.Array
    loss: jax.Array
    grad: jax.Array
    hess: jax.Array
    step_size: jax.Array
    first: jax.Array
    terminate: jax.Array
    steps: jax.Array


def _damped_step(hess, grad, step_size):
    """Solve (JᵀJ + λ I) δ = Jᵀr with λ = 1/step size, as optimistix's damped Newton descent."""
    tiny = step_size <= jnp.finfo(step_size.dtype).eps
    lam = jnp.where(tiny, jnp.finfo(step_size.dtype).max, 1.0 / jnp.where(tiny, 1.0, step_size))
    s, V = jnp.linalg.eigh(hess)
    return V @ ((V.T @ grad) / (jnp.maximum(s, 0.0) + lam))


# The bar of the fit in progress, advanced from inside the compiled solve (host side only).
_BARS: list = []


def _tick(steps):
    """Advance the current bar to the largest step count reached (one per start under vmap)."""
    if _BARS:
        done = int(np.max(np.asarray(steps)))
        if done > _BARS[-1].n:
            _BARS[-1].update(done - _BARS[-1].n)


def least_squares(params0, data, st: Settings, max_steps: int, report: bool = False):
    """Levenberg-Marquardt from `params0` on the chunked normal equations.

    **Arguments:** `params0`, the starting parameter dict; `data` as for [`normal_equations`][];
    `st`, the [`Settings`][] (with rtol/atol); `max_steps`, the step budget; `report`,
    advance the current progress bar after every step.

    **Returns:** `(params, loss, result, steps)`: the accepted parameters, their rᵀr, an
    `optx.RESULTS` code (`successful` or `nonlinear_max_steps_reached`) and the steps taken.
    """
    theta0, unravel = ravel_pytree(params0)
    p = theta0.shape[0]
    dtype = theta0.dtype

    def cond(s):
        return ~s.terminate & (s.steps < max_steps)

    def body(s):
        hess_e, grad_e, loss_e, change = normal_equations(s.y_eval, unravel, data, st, theta_old=s.y, first=s.first)
        d = s.y_eval - s.y
        predicted = s.grad @ d + 0.5 * d @ (s.hess @ d)
        actual = 0.5 * (loss_e - s.loss)
        accept = (actual <= 0.01 * predicted) | s.first
        good = (actual < 0.99 * predicted) & (predicted < 0) & ~s.first
        mul = jnp.where(accept, jnp.where(good, 3.5, 1.0), 0.25)
        step_size = mul * s.step_size
        y_small = jnp.max(jnp.abs(d) / (st.atol + st.rtol * jnp.abs(s.y_eval))) < 1
        terminate = accept & y_small & (change < 1)
        y = jnp.where(accept, s.y_eval, s.y)
        loss = jnp.where(accept, loss_e, s.loss)
        grad = jnp.where(accept, grad_e, s.grad)
        hess = jnp.where(accept, hess_e, s.hess)
        y_eval = y - _damped_step(hess, grad, step_size)
        if report:
            jax.debug.callback(_tick, s.steps + 1)
        return _LMState(y, y_eval, loss, grad, hess, step_size, jnp.array(False), terminate, s.steps + 1)

    zero = jnp.zeros((), dtype)
    init = _LMState(
        theta0,
        theta0,
        zero,
        jnp.zeros(p, dtype),
        jnp.zeros((p, p), dtype),
        jnp.ones((), dtype),
        jnp.array(True),
        jnp.array(False),
        jnp.array(0),
    )
    s = lax.while_loop(cond, body, init)
    result = optx.RESULTS.where(s.terminate, optx.RESULTS.successful, optx.RESULTS.nonlinear_max_steps_reached)
    return unravel(s.y), s.loss, result, s.steps


def solve_starts(
    r0s,
    un,
    yn,
    x0,
    mask,
    r_bound,
    *,
    positive_weights,
    fit_initial_states,
    max_steps,
    rtol,
    atol,
    active=None,
    z0=None,
    log_tau0s=None,
    lag_active=None,
    lag_base=None,
    chunk=None,
):
    """Every start (r0s (starts, n), log_tau0s (starts, K) or None) solved by the chunked
    Levenberg-Marquardt; the same arguments and returns as `fit._solve_starts`, and `chunk`, the
    samples per chunk (default `CHUNK`).

    When the record holds more than 2 `SCOUT` fitted samples, the starts are compared on the
    stretch that holds its first `SCOUT` fitted samples: each is solved there, the best is then
    solved again on every sample, and the others are scored on every sample as they are. A
    start that loses on 2^16 samples does not win on more, and the full-record solve from a
    converged start takes a few steps instead of a few dozen for every start.
    """
    chunk = CHUNK if chunk is None else int(chunk)
    used = np.flatnonzero(np.asarray(mask) > 0)
    scout = None
    if r0s.shape[0] > 1 and used.size > 2 * SCOUT:
        scout = -(-int(used[SCOUT - 1] + 1) // chunk)
        if 2 * scout * chunk > un.shape[0]:
            scout = None
    st = Settings(positive_weights, rtol, atol, r_bound, active, lag_active, x0, z0, lag_base)
    # The bar counts Levenberg-Marquardt steps on all samples (each one pass over the record),
    # against the budget: its estimate of the time left is an upper bound, as most fits stop
    # well before `max_steps`.
    _BARS.append(_bar(max_steps, desc=f"fit, steps on {used.size} samples"))
    try:
        out = _solve_starts(r0s, log_tau0s, un, yn, mask, st, fit_initial_states, max_steps, chunk, scout)
        return jax.block_until_ready(out)
    finally:
        _BARS.pop().close()


# Each play count, lag count and record length compiles its own large program; a structure
# search meets many once each, so only the latest two are kept (`_bounded_jit.py`).
@bounded_jit(2)
def _solve_starts(r0s, log_tau0s, un, yn, mask, st, fit_initial_states, max_steps, chunk, scout):
    # Padding repeats the last input (no play moves) and is masked out, as in `fit_data`.
    data = (chunked(un, un[-1], chunk), chunked(yn, 0.0, chunk), chunked(mask, 0.0, chunk))

    def one(r0, log_tau0, data, report):
        sol = start_regression(r0, log_tau0, data, st)
        p0 = _fit._initial_params(
            r0,
            un,
            yn,
            st.x0,
            mask,
            st.positive_weights,
            fit_initial_states,
            st.r_bound,
            st.active,
            st.z0,
            log_tau0,
            st.lag_active,
            st.lag_base,
            sol=sol,
        )
        params, loss, result, steps = least_squares(p0, data, st, max_steps, report)
        return params, jnp.where(jnp.isfinite(loss), loss, jnp.inf), result, steps

    if scout is None:
        return jax.vmap(lambda r0, k: one(r0, k, data, True))(r0s, log_tau0s)
    short = jax.tree.map(lambda a: a[:scout], data)
    params, loss, results, steps = jax.vmap(lambda r0, k: one(r0, k, short, False))(r0s, log_tau0s)
    best = jnp.argmin(loss)

    def full_loss(p):
        theta, unravel = ravel_pytree(p)
        return normal_equations(theta, unravel, data, st)[2]

    losses = jax.vmap(full_loss)(params)
    p, loss, result, more = least_squares(jax.tree.map(lambda a: a[best], params), data, st, max_steps, report=True)
    params = jax.tree.map(lambda a, b: a.at[best].set(b), params, p)
    losses = jnp.where(jnp.isfinite(losses), losses, jnp.inf).at[best].set(jnp.where(jnp.isfinite(loss), loss, jnp.inf))
    results = jax.tree.map(lambda a, b: b.at[best].set(a), result, results)
    return params, losses, results, steps.at[best].add(more)
