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
from .._data.stream import RecordStream
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
    - `start` (the first estimated sample), `window` (samples per PE window), `dt` (seconds per
      sample): how the record was read. Times above count from the record's first sample.
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
    start: int = eqx.field(static=True, default=0)
    window: int = eqx.field(static=True, default=0)
    dt: float = eqx.field(static=True, default=1.0)

    def to_json(self, t0: float = 0.0) -> dict:
        """The estimate as `piest estimate` writes it to estimate.json (less the command's own
        keys: the data file, the estimator's name and settings, the record's facts).

        **Arguments:** `t0`, the time of the record's first sample, added to every time.

        **Returns:** a JSON-ready dict: `start_time`, `start_sample`, `thresholds`,
        `initial_states`, `weights_final`, `offset_final`, `final_rmse`, `trajectory` (`t`,
        `weights`, `offset`, `error_rms`), `pe` (`window_s`, `t`, `level`, `exciting`,
        `all_exciting`) and `certificate` (`t`, `gram_bound`).
        """
        return dict(
            start_time=t0 + self.start * self.dt,
            start_sample=self.start,
            thresholds=self.thresholds,
            initial_states=self.initial_states,
            weights_final=self.weights,
            offset_final=float(self.offset),
            final_rmse=self.final_rmse,
            trajectory=dict(
                t=t0 + self.t, weights=self.weights_trajectory, offset=self.offset_trajectory, error_rms=self.error_rms
            ),
            pe=dict(
                window_s=self.window * self.dt,
                t=t0 + self.window_t,
                level=self.pe_levels,
                exciting=self.exciting,
                all_exciting=bool(np.all(np.asarray(self.exciting))),
            ),
            certificate=dict(t=t0 + self.bound_t, gram_bound=self.gram_bound),
        )


def _regressor_chunk(u, r, x0, a, offset: bool):
    H = play(u, r, x0, method="auto")
    Hn = H / a
    if offset:
        Hn = jnp.concatenate([Hn, jnp.ones((H.shape[0], 1), H.dtype)], axis=1)
    return H[-1], Hn


def _scan_chunk(estimator: AbstractEstimator, state, Hn, yn, valid):
    def body(state, hyv):
        h, yk, v = hyv
        new = estimator.step(state, h, yk)
        # Padding samples at the end of the last chunk leave the state as it was.
        new = jax.tree.map(lambda a, b: jnp.where(v, a, b), new, state)
        return new, (estimator.weights(new), jnp.where(v, estimator.prediction_error(new), 0.0))

    return lax.scan(body, state, (Hn, yn, valid))


@eqx.filter_jit
def _run_chunk_long(estimator: AbstractEstimator, state, Hn, yn, valid, boundary, cert: bool):
    """A chunk shorter than a window: the Gram (and information) of its samples before and
    after `boundary`, where the next window starts (at most one starts inside it)."""
    state, (w, e) = _scan_chunk(estimator, state, Hn, yn, valid)
    before = (jnp.arange(Hn.shape[0]) < boundary) & valid
    after = ~before & valid
    grams = [(Hn * m[:, None]).T @ Hn for m in (before, after)]
    if cert:
        assert isinstance(estimator, ContinuousRLS)  # the information is the continuous RLS's
        c = jax.vmap(lambda h: sample_weight(h, estimator.dt, estimator.normalisation))(Hn)
        infos = [(Hn * (c * m)[:, None]).T @ Hn for m in (before, after)]
    else:
        infos = [jnp.zeros_like(g) for g in grams]
    return state, w, e, *grams, *infos


@eqx.filter_jit
def _run_chunk(estimator: AbstractEstimator, state, Hn, yn, info, valid, window: int, cert: bool):
    state, (w, e) = _scan_chunk(estimator, state, Hn, yn, valid)
    n_win = Hn.shape[0] // window
    Hw = (Hn * valid[:, None])[: n_win * window].reshape(n_win, window, Hn.shape[1])
    gram = jnp.einsum("wti,wtj->wij", Hw, Hw) / window
    if not cert:
        eig = jnp.linalg.eigvalsh(gram)
        return state, w, e, eig[:, 0], eig[:, -1], info, jnp.zeros(n_win, Hn.dtype)
    # The information A = Σ c_i h_i h_iᵀ of the closed form, at the end of every window.
    assert isinstance(estimator, ContinuousRLS)  # cert: the continuous RLS only
    c = jax.vmap(lambda h: sample_weight(h, estimator.dt, estimator.normalisation))(Hn) * valid
    cw = c[: n_win * window].reshape(n_win, window)
    per_window = jnp.einsum("wt,wti,wtj->wij", cw, Hw, Hw)
    # One eigensolver call for both batches: two batched calls side by side can deadlock
    # XLA:CPU's intra-op thread pool on a two-core machine.
    eig = jnp.linalg.eigvalsh(jnp.concatenate([gram, info + jnp.cumsum(per_window, axis=0)]))
    info = info + jnp.einsum("t,ti,tj->ij", c, Hn, Hn)
    return state, w, e, eig[:n_win, 0], eig[:n_win, -1], info, eig[n_win:, 0]


class _Arrays:
    """A record in memory, with the few facts and the chunks that `RecordStream` provides."""

    def __init__(self, u, y):
        self.u, self.y = u, y
        self.n_samples, self.u_first = u.shape[0], float(u[0])
        self.u_min, self.u_max = float(u.min()), float(u.max())
        self.y_peak = float(np.max(np.abs(y)))

    def chunks(self, size: int):
        for k in range(0, self.n_samples, size):
            yield self.u[k : k + size], self.y[k : k + size]


def _as_record(u, y, dt) -> RecordStream | _Arrays:
    src: RecordStream | _Arrays
    if isinstance(u, RecordStream):
        if y is not None:
            raise ValueError("give `y` as None with a RecordStream: the stream holds both")
        src = u
    else:
        u = np.asarray(_checks.finite(_checks.signal(u, "u"), "u"))
        y = np.asarray(_checks.finite(_checks.signal(y, "y"), "y"))
        if u.shape != y.shape:
            raise ValueError(f"`u` has {u.shape[0]} samples but `y` has {y.shape[0]}")
        src = _Arrays(u, y)
    if src.n_samples < 2:
        raise ValueError(f"the record is too short: {src.n_samples} samples")
    if not (math.isfinite(float(dt)) and float(dt) > 0):
        raise ValueError(f"`dt` must be positive and finite, got {dt}")
    return src


def _blocks(src, first: int, stop: int, size: int):
    """`(u, y)` blocks of `size` samples covering samples first, ..., stop − 1 of `src` (the last
    block may be shorter), however `src` cuts its own chunks."""
    bu, by, have, pos = [], [], 0, 0
    for u, y in src.chunks(size):
        lo, hi = max(first - pos, 0), min(stop - pos, len(u))
        pos += len(u)
        if hi > lo:
            bu.append(u[lo:hi])
            by.append(y[lo:hi])
            have += hi - lo
            while have >= size:
                U, Y = (np.concatenate(b) if len(b) > 1 else b[0] for b in (bu, by))
                yield U[:size], Y[:size]
                bu, by, have = [U[size:]], [Y[size:]], have - size
        if pos >= stop:
            break
    if have:
        yield np.concatenate(bu), np.concatenate(by)


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
    - `u`, `y` (T,): the record; or `u` a [`RecordStream`][] (from [`open_record_stream`][]) and
      `y` None, read again in chunks for each pass (the plays' states up to `start`, the
      estimate, `final_rmse`), so memory does not grow with the record; `dt`: its sampling step
      in seconds.
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
    src = _as_record(u, y, dt)
    T_all = src.n_samples
    if not 0 <= int(start) <= T_all - 2:
        raise ValueError(f"`start` must leave at least 2 samples of the record's {T_all}, got {start}")
    start = int(start)
    checked = _checks.thresholds(thresholds, "thresholds")
    if checked.ndim != 1 or checked.shape[0] < 1:
        raise ValueError(f"`thresholds` must be a vector of at least one threshold, got shape {checked.shape}")
    r = np.asarray(checked, float)
    n = r.shape[0]
    x0 = np.full(n, src.u_first) if initial_states is None else np.asarray(initial_states, float)
    if x0.shape != (n,) or not np.all(np.isfinite(x0)):
        raise ValueError(f"`initial_states` must be {n} finite values, one per play, got {x0.shape}")
    if start:
        # The plays' states at `start`, from the samples before it.
        x0 = np.asarray(_final_states(_blocks(src, 0, start, chunk), r, x0), float)
    T = T_all - start
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
    # The scales of the whole record (also the samples before `start`), as the stream knows them.
    a = max(abs(src.u_min), abs(src.u_max), float(np.max(np.abs(x0))), 1e-300) if rescale else 1.0
    b = max(src.y_peak, 1e-300) if rescale else 1.0
    # Chunks hold whole windows, or when a window is longer than a chunk, a chunk holds at most
    # one window's start and the window's Gram is summed over chunks: memory is set by `chunk`.
    long_windows = window > chunk
    chunk = chunk if long_windows else (chunk // window) * window
    cert = isinstance(estimator, ContinuousRLS)
    m = n + int(offset)
    gram_acc, info_acc = np.zeros((m, m)), np.zeros((m, m))
    state = estimator.init(jnp.zeros(m, dtype))
    info = jnp.zeros((m, m), dtype)
    x = jnp.asarray(x0, dtype)
    rj = jnp.asarray(r, dtype)
    # The kept instants: `keep` evenly spaced samples, the last one included.
    marks = np.unique(np.linspace(0, T - 1, min(keep, T)).round().astype(int))
    w_keep, lam_min, lam_max, infos = [], [], [], []
    e_sq_cum = 0.0
    err_at_marks = []
    for first, (ub, yb) in zip(range(0, T, chunk), _blocks(src, start, T_all, chunk)):
        stop = min(first + chunk, T)
        size = stop - first
        pad = chunk - size
        uc = np.concatenate([ub, np.full(pad, ub[-1])])
        yc = np.concatenate([yb, np.zeros(pad)]) / b
        valid = jnp.asarray(np.arange(chunk) < size)
        # Padding repeats the last input, which moves no play: the carried state is exact.
        x, Hn = _regressor_chunk(jnp.asarray(uc, dtype), rj, x, jnp.asarray(a, dtype), offset)
        if long_windows:
            boundary = (first // window + 1) * window - first
            # The boundary is traced, not static: one compiled program for every chunk.
            state, w, e, G0, G1, I0, I1 = _run_chunk_long(
                estimator, state, Hn, jnp.asarray(yc, dtype), valid, jnp.asarray(boundary), cert
            )
            gram_acc += np.asarray(G0)
            info_acc += np.asarray(I0)
            if boundary <= size:  # a window ends in this chunk
                eig = np.linalg.eigvalsh(gram_acc / window)
                lam_min.append(eig[:1])
                lam_max.append(eig[-1:])
                infos.append(np.linalg.eigvalsh(info_acc)[:1])
                gram_acc = np.array(G1)
            info_acc += np.asarray(I1)
        else:
            state, w, e, lo, hi, info, info_min = _run_chunk(
                estimator, state, Hn, jnp.asarray(yc, dtype), info, valid, window, cert
            )
            full = size // window
            lam_min.append(np.asarray(lo[:full]))
            lam_max.append(np.asarray(hi[:full]))
            infos.append(np.asarray(info_min[:full]))
        w, e = np.asarray(w[:size]), np.asarray(e[:size])
        in_chunk = marks[(marks >= first) & (marks < stop)] - first
        cum = np.cumsum(e.astype(float) ** 2) + e_sq_cum
        for k in in_chunk:
            w_keep.append(w[k].copy())  # a row, not a view that would keep the chunk alive
            idx = first + k
            err_at_marks.append((cum[k], idx))
        e_sq_cum = float(cum[-1])
    W = np.asarray(w_keep) * (b / np.concatenate([np.full(n, a), np.ones(int(offset))]))
    prev_sq, prev_i, rms = 0.0, -1, []
    for s, i in err_at_marks:
        rms.append(math.sqrt(max(s - prev_sq, 0.0) / (i - prev_i)) * b)
        prev_sq, prev_i = s, i
    weights = W[-1, :n]
    off = float(W[-1, n]) if offset else 0.0
    final_rmse = _final_rmse(_blocks(src, start, T_all, chunk), T, r, x0, weights, off)
    lo, hi = np.concatenate(lam_min), np.concatenate(lam_max)
    exciting = lo > numerical_tolerance(dtype) * np.maximum(hi, 1e-300)
    if cert:
        assert isinstance(estimator, ContinuousRLS)
        P0 = np.asarray(estimator.P0, float)
        r0 = np.linalg.eigvalsh(np.linalg.inv(P0 if P0.ndim == 2 else P0 * np.eye(m)))
        bound = r0[-1] / (r0[0] + np.maximum(np.concatenate(infos), 0.0))
        chunk_t = ((np.arange(len(bound)) + 1) * window - 1 + start) * float(dt)
    else:
        bound, chunk_t = np.zeros(0), np.zeros(0)
    return OnlineEstimate(
        thresholds=jnp.asarray(r),
        initial_states=jnp.asarray(x0),
        weights=jnp.asarray(weights),
        offset=jnp.asarray(off),
        t=jnp.asarray((marks + start) * float(dt)),
        weights_trajectory=jnp.asarray(W[:, :n]),
        offset_trajectory=jnp.asarray(W[:, n] if offset else np.zeros(len(W))),
        error_rms=jnp.asarray(rms),
        final_rmse=final_rmse,
        window_t=jnp.asarray((np.arange(len(lo)) * window + start) * float(dt)),
        pe_levels=jnp.asarray(lo),
        exciting=jnp.asarray(exciting),
        bound_t=jnp.asarray(chunk_t),
        gram_bound=jnp.asarray(bound),
        start=start,
        window=window,
        dt=float(dt),
    )


def _final_rmse(blocks, T, r, x0, weights, offset) -> float:
    """RMSE over the record of the PI model with the final weights, computed block by block."""
    dtype = jnp.result_type(float)
    x = jnp.asarray(x0, dtype)
    rj, wj = jnp.asarray(r, dtype), jnp.asarray(weights, dtype)
    sse = 0.0
    for u, y in blocks:
        H = play(jnp.asarray(u, dtype), rj, x, method="auto")
        x = H[-1]
        pred = np.asarray(H @ wj, float) + offset
        sse += float(np.sum((pred - y) ** 2))
    return math.sqrt(sse / T)


def _final_states(blocks, r, x0):
    dtype = jnp.result_type(float)
    x, rj = jnp.asarray(x0, dtype), jnp.asarray(r, dtype)
    for u, _ in blocks:
        x = play(jnp.asarray(u, dtype), rj, x, method="auto")[-1]
    return x


def settled_start(u, *, tolerance: float = 0.02) -> int:
    """The first sample after which the plays no longer depend on their unknown initial states.

    Once the input has visited both ends of its range (within `tolerance` of the peak-to-peak
    range), every play with a threshold below half that range has been driven to a state set by
    the input alone (the wiping-out property), whatever its state before the record began. A
    record that starts from an unknown history (a device at rest after earlier use) is estimated
    from there. When that takes more than half the record, 0 (estimate from the start).

    **Arguments:** `u` (T,), the input, or a [`RecordStream`][] (read in chunks); `tolerance`, as
    a fraction of max u − min u.

    **Returns:** a sample index.
    """
    src: RecordStream | _Arrays
    if isinstance(u, RecordStream):
        src = u
    else:
        u = np.asarray(u, float)
        src = _Arrays(u, u)  # the input alone: its chunks' second half is unused
    lo, hi = src.u_min, src.u_max
    if not (np.isfinite(lo) and np.isfinite(hi)):
        raise ValueError(f"`u` must be finite to find where the plays settle; its range is [{lo}, {hi}]")
    band = tolerance * (hi - lo)
    if not hi - lo > 0:
        return 0
    first_max = first_min = None
    pos = 0
    for uc, _ in src.chunks(DEFAULT_CHUNK):
        if first_max is None and np.any(uc >= hi - band):
            first_max = pos + int(np.argmax(uc >= hi - band))
        if first_min is None and np.any(uc <= lo + band):
            first_min = pos + int(np.argmax(uc <= lo + band))
        pos += len(uc)
        if first_max is not None and first_min is not None:
            break
    # The input reaches its own maximum and minimum (hi - lo > 0), so both were found.
    assert first_max is not None and first_min is not None
    k = max(first_max, first_min)
    return k if k <= src.n_samples // 2 else 0
