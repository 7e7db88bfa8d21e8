"""Online estimation on a measured record, streamed in chunks.

The paper's estimators consume one sample at a time; a record of 10⁷ samples should not need its
(T, n) regressor in memory. `estimate_record` runs the play bank and the estimator chunk by
chunk, carrying both states (the plays' states and the estimator's state) from one chunk to the
next, and keeps only what a user reads afterwards: the weight trajectory at a fixed number of
instants, the PE level of every window, the information accumulated by the continuous RLS (its
convergence certificate) at the end of every chunk, and the final weights. Memory is set by the
chunk length and the number of kept instants, not by the record's length.

Units: by default (`rescale=True`) the estimator runs on H / a and y / b with a and b the
input's and output's peak magnitudes (known from the record before it runs, or from the sensors'
ranges online), so P0 and the gains refer to data of magnitude one whatever the units; weights,
errors and the offset are reported in the data's units.
"""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jaxtyping import Array, Float

from .. import _checks
from .._excitation.map_settings import numerical_tolerance
from .._operators.play import play
from .estimators import AbstractEstimator, check_estimator
from .rls import ContinuousRLS, sample_weight

DEFAULT_CHUNK = 1 << 16
DEFAULT_KEEP = 2000


class OnlineEstimate(eqx.Module):
    """The result of [`estimate_record`][], in the data's units.

    **Fields:**

    - `thresholds` (n,), `initial_states` (n,): the play bank that was used, with its states
      before the first estimated sample (`start`).
    - `weights` (n,), `offset` (scalar; 0 when no offset was estimated): after the last sample.
    - `t` (K,), `weights_trajectory` (K, n), `offset_trajectory` (K,): the estimate at K instants
      spread over the record (the last one is the final sample).
    - `error_rms` (K,): the RMS a-priori prediction error over the samples since the previous
      instant.
    - `final_rmse`: RMSE over the whole record of the model with the final weights and offset.
    - `window_t` (W,), `pe_levels` (W,): the start time and the PE level (smallest eigenvalue of
      the window's Gram matrix of the normalised regressor, Definition 1) of each complete
      window; `exciting` (W,) whether it is above rounding (`numerical_tolerance`).
    - `bound_t` (W,), `gram_bound` (W,): for `ContinuousRLS`, the bound on the relative
      noise-free weight error ‖Ŵ − W‖ / ‖Ŵ0 − W‖ from the information accumulated up to the end of
      each window (the `gram_bound` of [`convergence_certificate`][]); empty otherwise.
    """

    thresholds: Float[Array, " n"]
    initial_states: Float[Array, " n"]
    weights: Float[Array, " n"]
    offset: Array
    t: Float[Array, " K"]
    weights_trajectory: Float[Array, "K n"]
    offset_trajectory: Float[Array, " K"]
    error_rms: Float[Array, " K"]
    final_rmse: float
    window_t: Float[Array, " W"]
    pe_levels: Float[Array, " W"]
    exciting: Array
    bound_t: Float[Array, " W"]
    gram_bound: Float[Array, " W"]


def _regressor_chunk(u, r, x0, a, offset: bool):
    H = play(u, r, x0, method="auto")
    Hn = H / a
    if offset:
        Hn = jnp.concatenate([Hn, jnp.ones((H.shape[0], 1), H.dtype)], axis=1)
    return H[-1], Hn


@eqx.filter_jit
def _run_chunk(estimator: AbstractEstimator, state, Hn, yn, info, valid, window: int, cert: bool):
    def body(state, hyv):
        h, yk, v = hyv
        new = estimator.step(state, h, yk)
        # Padding samples at the end of the last chunk leave the state as it was.
        new = jax.tree.map(lambda a, b: jnp.where(v, a, b), new, state)
        return new, (estimator.weights(new), jnp.where(v, estimator.prediction_error(new), 0.0))

    state, (w, e) = lax.scan(body, state, (Hn, yn, valid))
    n_win = Hn.shape[0] // window
    Hw = (Hn * valid[:, None])[: n_win * window].reshape(n_win, window, Hn.shape[1])
    gram = jnp.einsum("wti,wtj->wij", Hw, Hw) / window
    if not cert:
        eig = jnp.linalg.eigvalsh(gram)
        return state, w, e, eig[:, 0], eig[:, -1], info, jnp.zeros(n_win, Hn.dtype)
    # The information A = Σ c_i h_i h_iᵀ of the closed form, at the end of every window.
    c = jax.vmap(lambda h: sample_weight(h, estimator.dt, estimator.normalisation))(Hn) * valid
    cw = c[: n_win * window].reshape(n_win, window)
    per_window = jnp.einsum("wt,wti,wtj->wij", cw, Hw, Hw)
    # One eigensolver call for both batches: two batched calls side by side can deadlock
    # XLA:CPU's intra-op thread pool on a two-core machine.
    eig = jnp.linalg.eigvalsh(jnp.concatenate([gram, info + jnp.cumsum(per_window, axis=0)]))
    info = info + jnp.einsum("t,ti,tj->ij", c, Hn, Hn)
    return state, w, e, eig[:n_win, 0], eig[:n_win, -1], info, eig[n_win:, 0]


def _as_record(u, y, dt):
    u = np.asarray(_checks.finite(_checks.signal(u, "u"), "u"))
    y = np.asarray(_checks.finite(_checks.signal(y, "y"), "y"))
    if u.shape != y.shape:
        raise ValueError(f"`u` has {u.shape[0]} samples but `y` has {y.shape[0]}")
    if u.shape[0] < 2:
        raise ValueError(f"the record is too short: {u.shape[0]} samples")
    if not (math.isfinite(float(dt)) and float(dt) > 0):
        raise ValueError(f"`dt` must be positive and finite, got {dt}")
    return u, y


def estimate_record(
    estimator: AbstractEstimator,
    u,
    y,
    thresholds,
    *,
    dt: float,
    initial_states=None,
    offset: bool = True,
    window: int | None = None,
    rescale: bool = True,
    chunk: int = DEFAULT_CHUNK,
    keep: int = DEFAULT_KEEP,
    start: int = 0,
) -> OnlineEstimate:
    """Run an online estimator over a measured record, in chunks of bounded memory.

    **Arguments:**

    - `estimator`: e.g. `ContinuousRLS(P0=1e6, dt=dt)` (the paper's), `ForgettingRLS(...)` or
      `NormalisedGradient(...)`, with one weight per play, plus one for the offset when `offset`
      (a scalar P0 fits any size).
    - `u`, `y` (T,): the record; `dt`: its sampling step in seconds.
    - `thresholds` (n,): the play thresholds; `initial_states` (n,): the plays' states before
      the first sample (default: relaxed at u_0).
    - `offset`: estimate an output offset as one more weight (a constant regressor).
    - `window`: samples per PE window (default: a tenth of the record, at least 2).
    - `rescale`: run on normalised data (see the module docstring); the weights are reported
      in the data's units either way.
    - `chunk`: samples per chunk (rounded to whole windows); `keep`: instants kept in the
      trajectory.
    - `start`: the first sample the estimator sees; the plays run through the samples before it
      (so their states carry over), which are left out of the estimate and of `final_rmse` (a
      record that starts with the device at rest from an unknown history, say).

    **Returns:** an [`OnlineEstimate`][].
    """
    u, y = _as_record(u, y, dt)
    if not 0 <= int(start) <= u.shape[0] - 2:
        raise ValueError(f"`start` must leave at least 2 samples of the record's {u.shape[0]}, got {start}")
    r = _checks.thresholds(thresholds, "thresholds")
    if r.ndim != 1 or r.shape[0] < 1:
        raise ValueError(f"`thresholds` must be a vector of at least one threshold, got shape {r.shape}")
    r = np.asarray(r, float)
    n = r.shape[0]
    x0 = np.full(n, u[0]) if initial_states is None else np.asarray(initial_states, float)
    if x0.shape != (n,) or not np.all(np.isfinite(x0)):
        raise ValueError(f"`initial_states` must be {n} finite values, one per play, got {x0.shape}")
    if start:
        # The plays' states at `start`, from the samples before it.
        x0 = np.asarray(_final_states(u[:start], r, x0, chunk), float)
        u, y = u[start:], y[start:]
    T = u.shape[0]
    window = max(2, T // 10) if window is None else int(window)
    if not 2 <= window <= T:
        raise ValueError(f"`window` must be between 2 and the record's {T} samples, got {window}")
    if keep < 1 or chunk < 1:
        raise ValueError("`keep` and `chunk` must be positive")
    check_estimator(estimator)
    expected = estimator.n_plays
    if expected is not None and expected != n + offset:
        raise ValueError(
            f"the estimator is set up for {expected} weights but the model has {n + offset} "
            f"({n} plays{' and an offset' if offset else ''})"
        )
    dtype = jnp.result_type(float)
    a = max(float(np.max(np.abs(u))), float(np.max(np.abs(x0))), 1e-300) if rescale else 1.0
    b = max(float(np.max(np.abs(y))), 1e-300) if rescale else 1.0
    chunk = max(window, (chunk // window) * window)
    cert = isinstance(estimator, ContinuousRLS)
    m = n + int(offset)
    state = estimator.init(jnp.zeros(m, dtype))
    info = jnp.zeros((m, m), dtype)
    x = jnp.asarray(x0, dtype)
    rj = jnp.asarray(r, dtype)
    # The kept instants: `keep` evenly spaced samples, the last one included.
    marks = np.unique(np.linspace(0, T - 1, min(keep, T)).round().astype(int))
    w_keep, lam_min, lam_max, infos = [], [], [], []
    e_sq_cum = 0.0
    err_at_marks = []
    for first in range(0, T, chunk):
        stop = min(first + chunk, T)
        size = stop - first
        pad = chunk - size
        uc = np.concatenate([u[first:stop], np.full(pad, u[stop - 1])])
        yc = np.concatenate([y[first:stop], np.zeros(pad)]) / b
        valid = jnp.asarray(np.arange(chunk) < size)
        # Padding repeats the last input, which moves no play: the carried state is exact.
        x, Hn = _regressor_chunk(jnp.asarray(uc, dtype), rj, x, jnp.asarray(a, dtype), offset)
        state, w, e, lo, hi, info, info_min = _run_chunk(estimator, state, Hn, jnp.asarray(yc, dtype), info, valid,
                                                         window, cert)
        w, e = np.asarray(w[:size]), np.asarray(e[:size])
        in_chunk = marks[(marks >= first) & (marks < stop)] - first
        cum = np.cumsum(e.astype(float) ** 2) + e_sq_cum
        for k in in_chunk:
            w_keep.append(w[k])
            idx = first + k
            err_at_marks.append((cum[k], idx))
        e_sq_cum = float(cum[-1])
        full = size // window
        lam_min.append(np.asarray(lo[:full]))
        lam_max.append(np.asarray(hi[:full]))
        infos.append(np.asarray(info_min[:full]))
    W = np.asarray(w_keep) * (b / np.concatenate([np.full(n, a), np.ones(int(offset))]))
    prev_sq, prev_i, rms = 0.0, -1, []
    for s, i in err_at_marks:
        rms.append(math.sqrt(max(s - prev_sq, 0.0) / (i - prev_i)) * b)
        prev_sq, prev_i = s, i
    weights = W[-1, :n]
    off = float(W[-1, n]) if offset else 0.0
    final_rmse = _final_rmse(u, y, r, x0, weights, off, chunk)
    lo, hi = np.concatenate(lam_min), np.concatenate(lam_max)
    exciting = lo > numerical_tolerance(dtype) * np.maximum(hi, 1e-300)
    if cert:
        P0 = np.asarray(estimator.P0, float)
        r0 = np.linalg.eigvalsh(np.linalg.inv(P0 if P0.ndim == 2 else P0 * np.eye(m)))
        bound = r0[-1] / (r0[0] + np.maximum(np.concatenate(infos), 0.0))
        chunk_t = ((np.arange(len(bound)) + 1) * window - 1 + start) * float(dt)
    else:
        bound, chunk_t = np.zeros(0), np.zeros(0)
    return OnlineEstimate(
        thresholds=jnp.asarray(r), initial_states=jnp.asarray(x0), weights=jnp.asarray(weights),
        offset=jnp.asarray(off), t=jnp.asarray((marks + start) * float(dt)), weights_trajectory=jnp.asarray(W[:, :n]),
        offset_trajectory=jnp.asarray(W[:, n] if offset else np.zeros(len(W))),
        error_rms=jnp.asarray(rms), final_rmse=final_rmse,
        window_t=jnp.asarray((np.arange(len(lo)) * window + start) * float(dt)), pe_levels=jnp.asarray(lo),
        exciting=jnp.asarray(exciting), bound_t=jnp.asarray(chunk_t), gram_bound=jnp.asarray(bound),
    )


def _final_rmse(u, y, r, x0, weights, offset, chunk) -> float:
    """RMSE over the record of the PI model with the final weights, computed chunk by chunk."""
    dtype = jnp.result_type(float)
    x = jnp.asarray(x0, dtype)
    rj, wj = jnp.asarray(r, dtype), jnp.asarray(weights, dtype)
    sse = 0.0
    for start in range(0, len(u), chunk):
        H = play(jnp.asarray(u[start : start + chunk], dtype), rj, x, method="auto")
        x = H[-1]
        pred = np.asarray(H @ wj, float) + offset
        sse += float(np.sum((pred - y[start : start + chunk]) ** 2))
    return math.sqrt(sse / len(u))


def _final_states(u, r, x0, chunk):
    dtype = jnp.result_type(float)
    x, rj = jnp.asarray(x0, dtype), jnp.asarray(r, dtype)
    for s in range(0, len(u), chunk):
        x = play(jnp.asarray(u[s : s + chunk], dtype), rj, x, method="auto")[-1]
    return x


def settled_start(u, *, tolerance: float = 0.02) -> int:
    """The first sample after which the plays no longer depend on their unknown initial states.

    Once the input has visited both ends of its range (within `tolerance` of the peak-to-peak
    range), every play with a threshold below half that range has been driven to a state set by
    the input alone (the wiping-out property), whatever its state before the record began. A
    record that starts from an unknown history (a device at rest after earlier use) is estimated
    from there. When that takes more than half the record, 0 (estimate from the start).

    **Arguments:** `u` (T,), the input; `tolerance`, as a fraction of max u − min u.

    **Returns:** a sample index.
    """
    u = np.asarray(u, float)
    lo, hi = float(u.min()), float(u.max())
    band = tolerance * (hi - lo)
    if not hi - lo > 0:
        return 0
    at_max = np.flatnonzero(u >= hi - band)
    at_min = np.flatnonzero(u <= lo + band)
    k = int(max(at_max[0], at_min[0]))
    return k if k <= len(u) // 2 else 0
