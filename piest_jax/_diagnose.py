"""Name the effects a plain PI model misses: fit, score candidates on held-out blocks, repeat.

The loop: fit the base PI model (offset, relaxed initial states); for every effect not yet in the
model, add it, refit from the current fit, and measure the error on held-out blocks (contiguous,
interleaved with the fitting blocks, so the model runs through them and start-up, holds and cycles
are all represented). The best candidate is named only if its held-out gain is large against the
noise floor, consistent across held-out blocks, and a real share of the remaining error; then the
loop repeats on what remains. Long records are sub-sampled for the search (the model's time
constants and delay are physical, so the chosen model is then evaluated at full rate).
"""

import dataclasses

import numpy as np

from . import _effects, _locate
from ._data import DataError, Record

MIN_SAMPLES = 200
SEARCH_SAMPLES = 2048
_BUCKETS = (512, 768, 1024, 1536, 2048)
N_BLOCKS = 32
# Naming thresholds, in units of the noise variance and of the current held-out MSE: an effect must
# remove at least this much held-out error. (The per-block t statistic is reported but not used:
# a real effect often lives in a few blocks, start-up or holds, where a t test across blocks is weak,
# while the noise in the held-out gain itself is small, about 2 sigma |change| / sqrt(N).)
MIN_GAIN_NOISE = 0.4
MIN_GAIN_REL = 0.03
PARAM_PENALTY = 2.0  # held-out MSE is further charged PARAM_PENALTY * sigma^2 * p / N_heldout
MAX_EFFECTS = 3
_DELAY_GRID = (0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0)  # in full-rate samples
# Where one start is not enough: the dynamics' natural frequency (in units of ten times the input's
# dominant frequency) and damping have local minima; the better fit on the fitting blocks is kept.
_EXTRA_STARTS = {
    "linear_dynamics": [None, np.array([np.log(0.35), np.log(np.expm1(0.35))])],
}


def noise_std(y) -> float:
    """The noise floor: a robust std of second differences over sqrt(6).

    For white noise of std sigma on a smooth signal, the second difference has std sigma sqrt(6); the
    median absolute deviation ignores the few samples at reversals and steps.

    **Arguments:** `y`, a sampled signal (T,).

    **Returns:** the estimated noise std.
    """
    d2 = np.diff(np.asarray(y, float), 2)
    mad = np.median(np.abs(d2 - np.median(d2)))
    return float(1.4826 * mad / np.sqrt(6.0))


@dataclasses.dataclass(frozen=True)
class Scaling:
    """The normalisation of one identification record, reused for validation records."""

    u_mid: float
    u_half: float
    y_mid: float
    y_half: float
    rate_scale: float
    omega_ref: float
    period: float
    delay_unit: float


def check_record(rec: Record) -> None:
    """Refuse records the diagnosis cannot use, with a message naming the problem.

    **Arguments:** `rec`, a `Record`.

    **Returns:** nothing; raises `DataError` for too few samples, NaN/inf, an input with no
    excitation or a constant output.
    """
    src = rec.source
    if rec.n_samples < MIN_SAMPLES:
        raise DataError(f"{src}: too short: {rec.n_samples} samples, the diagnosis needs {MIN_SAMPLES}")
    for name, col in (("t", rec.t), ("u", rec.u), ("y", rec.y)):
        bad = ~np.isfinite(col)
        if bad.any():
            raise DataError(
                f"{src}: column `{name}` has {int(bad.sum())} NaN/inf values "
                f"(first at row {int(np.argmax(bad))}); remove or fill them"
            )
    if not np.all(np.diff(rec.t) > 0):
        raise DataError(f"{src}: time stamps are not strictly increasing")
    du = np.ptp(rec.u)
    if du <= 1e-9 * np.max(np.abs(rec.u)):
        raise DataError(f"{src}: no excitation: the input u is constant, nothing can be identified")
    un = (rec.u - rec.u.min()) / du
    if _reversals(un) < 2:
        raise DataError(
            f"{src}: no excitation: the input never reverses direction, so no hysteresis loop "
            "is traced; record at least one rise and fall"
        )
    if np.ptp(rec.y) <= 1e-9 * np.max(np.abs(rec.y)):
        raise DataError(f"{src}: constant output: y does not change, there is nothing to model")


def _reversals(un, frac=0.05):
    """Direction changes of a signal in [0, 1] larger than `frac` (a hysteresis counter)."""
    count, ext, direction = 0, un[0], 0
    for v in un[:: max(1, len(un) // 20000)]:
        if direction == 0:
            if abs(v - ext) > frac:
                direction, ext = (1 if v > ext else -1), v
        elif direction * (v - ext) > 0:
            ext = v
        elif direction * (ext - v) > frac:
            count, direction, ext = count + 1, -direction, v
    return count


def scaling_of(rec: Record) -> Scaling:
    """The normalisation constants of an identification record.

    **Arguments:** `rec`, the record.

    **Returns:** a `Scaling`.
    """
    u_mid, u_half = 0.5 * (rec.u.max() + rec.u.min()), 0.5 * np.ptp(rec.u)
    y_mid, y_half = 0.5 * (rec.y.max() + rec.y.min()), 0.5 * np.ptp(rec.y)
    rate = np.abs(np.gradient((rec.u - u_mid) / u_half, rec.t))
    rate_scale = float(np.percentile(rate, 90)) or float(rate.max())
    duration = float(rec.t[-1] - rec.t[0])
    f_dom = max(_reversals((rec.u - rec.u.min()) / np.ptp(rec.u)) / 2, 1.0) / duration
    return Scaling(
        float(u_mid), float(u_half), float(y_mid), float(y_half), rate_scale,
        float(2 * np.pi * 10 * f_dom), float(1 / f_dom), rec.dt,
    )


def model_data(rec: Record, sc: Scaling, *, step=1, length=None, fit_w=None):
    """A record in the model's normalised units, optionally sub-sampled and padded to `length`."""
    import jax.numpy as jnp

    u = (rec.u - sc.u_mid) / sc.u_half
    y = (rec.y - sc.y_mid) / sc.y_half
    rho = np.abs(np.gradient(u, rec.t)) / sc.rate_scale
    s = (rec.t - rec.t[0]) / max(rec.t[-1] - rec.t[0], 1e-300)
    u, y, rho, s = (a[::step] for a in (u, y, rho, s))
    n = len(u)
    w = np.ones(n) if fit_w is None else np.asarray(fit_w, float)
    if length is not None and length > n:
        pad = length - n
        u, y, rho, s = (np.concatenate([a, np.full(pad, a[-1])]) for a in (u, y, rho, s))
        w = np.concatenate([w, np.zeros(pad)])
    f = lambda a: jnp.asarray(a, dtype=jnp.float64)  # noqa: E731
    return _effects.ModelData(
        f(u), f(y), f(rho), f(s), f(w), f(rec.dt * step), f(sc.delay_unit), f(sc.omega_ref),
        f(sc.period),
    )


def _base_start(data, n):
    """Base parameters with weights from linear least squares on the starting threshold grid."""
    import jax.numpy as jnp

    from ._play import play

    th = _effects.initial_params()
    r = np.asarray(_effects.thresholds_of(jnp.asarray(th)))
    u = np.asarray(data.u)[:n]
    X = np.asarray(play(u, r, u[0]))
    A = np.column_stack([X, np.ones(n)])
    w = np.asarray(data.fit_w)[:n]
    coef, *_ = np.linalg.lstsq(A * w[:, None], np.asarray(data.y)[:n] * w, rcond=None)
    base = _effects._sl("base")
    th[base.start + _effects.N_PLAYS - 1 : base.stop] = coef
    return th


def _bucket(n):
    """A padded length from a few sizes, so records of similar length share one compilation."""
    fits = [b for b in _BUCKETS if b >= n]
    return fits[0] if fits else int(np.ceil(n / _BUCKETS[-1])) * _BUCKETS[-1]


def _blocks(n):
    return np.minimum((np.arange(n) * N_BLOCKS) // n, N_BLOCKS - 1)


def _score(pred_cur, pred_new, y, held, blocks):
    e_cur, e_new = (pred_cur - y) ** 2, (pred_new - y) ** 2
    d = np.array([np.mean((e_cur - e_new)[held & (blocks == b)]) for b in np.unique(blocks[held])])
    t = d.mean() / (d.std(ddof=1) / np.sqrt(len(d)) + 1e-300)
    return float(np.mean(e_cur[held]) - np.mean(e_new[held])), float(t)


def _delay_starts(theta, names, data, y, fit_mask, n):
    """Two starts for the delay, each from the best of a log-spaced grid on the fitting blocks.

    The delay enters through interpolation, so its error surface is rippled at the scale of a
    sample and the solver alone can stall far from a delay of many samples. Worse, a plain PI fit
    absorbs a delay by widening its loop, so the current fit is a poor start for a long delay. The
    second start therefore goes back to the neutral threshold grid and, for each delay on the grid,
    refits the weights and offset by linear least squares on the delayed play outputs.
    """
    import jax.numpy as jnp

    from ._play import play

    g = jnp.asarray(_effects.group_mask(names))
    sl, base = _effects._sl("delay"), _effects._sl("base")
    wsl = slice(base.start + _effects.N_PLAYS - 1, base.stop)
    steps = float(data.delay_unit / data.dt)
    neutral = _effects.initial_params()
    r = np.asarray(_effects.thresholds_of(jnp.asarray(neutral)))
    u = np.asarray(data.u)[:n]
    X = np.asarray(play(u, r, u[0]))
    idx = np.arange(n, dtype=float)
    w = fit_mask.astype(float)
    best_cur = best_new = None
    for d in _DELAY_GRID:
        th = theta.copy()
        th[sl] = np.log(np.expm1(d))
        pred = np.asarray(_effects.predict_jit(jnp.asarray(th), g, data))[:n]
        sse = float(np.sum(((pred - y) ** 2)[fit_mask]))
        if best_cur is None or sse < best_cur[0]:
            best_cur = (sse, th)
        Xd = np.column_stack([np.interp(idx - d * steps, idx, X[:, j]) for j in range(X.shape[1])] + [np.ones(n)])
        coef, *_ = np.linalg.lstsq(Xd * w[:, None], y * w, rcond=None)
        sse = float(np.sum(((Xd @ coef - y) ** 2)[fit_mask]))
        if best_new is None or sse < best_new[0]:
            th = theta.copy()
            th[base] = neutral[base]
            th[wsl] = coef
            th[sl] = np.log(np.expm1(d))
            best_new = (sse, th)
    return [best_cur[1], best_new[1]]


def _prune(named, theta, pred, run_fit, y, held, sigma2, n_held):
    """Drop a named effect that a later one made redundant (backward elimination).

    A first-order lag can stand in for a delay, a delay for a lag: when the later effect explains
    what the earlier one did, the model without the earlier effect is as good on held-out blocks.
    """
    pruned = []
    start = _effects.initial_params()
    changed = len(named) > 1
    while changed and len(named) > 1:
        changed = False
        mse = float(np.mean((pred[held] - y[held]) ** 2))
        for e in list(named):
            rest = [x for x in named if x != e]
            th0 = theta.copy()
            th0[_effects._sl(e)] = start[_effects._sl(e)]
            th_r, pred_r = run_fit(th0, rest)
            loss = float(np.mean((pred_r[held] - y[held]) ** 2)) - mse
            bonus = PARAM_PENALTY * sigma2 * _effects.n_effect_params(e) / n_held
            if loss - bonus < MIN_GAIN_NOISE * sigma2 or loss < MIN_GAIN_REL * mse:
                named, theta, pred, changed = rest, th_r, pred_r, True
                pruned.append(e)
                break
    return named, theta, pred, pruned


def search(rec: Record, *, max_effects: int = MAX_EFFECTS, candidates=_effects.EFFECTS, refit: bool = True):
    """Run the naming loop on one identification record.

    **Arguments:**

    - `rec`: the record (checked with `check_record`).
    - `max_effects`: stop after naming this many.
    - `candidates`: the effects to consider.
    - `refit`: refit the base and final models on every sample (fitting and held-out blocks)
      once the effects are chosen; without it the search's fits are returned.

    **Returns:** a dict with `effects` (named, in order), `rounds` (each candidate's held-out RMSE,
    gain and t statistic per round), `theta_base`, `theta_final`, `groups`, `scaling`, the noise
    estimate and held-out RMSEs (normalised units are converted back to the data's units).
    """
    import jax.numpy as jnp

    candidates = list(candidates)
    for c in candidates:
        _effects.n_effect_params(c)
    check_record(rec)
    sc = scaling_of(rec)
    step = int(np.ceil(rec.n_samples / SEARCH_SAMPLES))
    n = len(rec.u[::step])
    length = _bucket(n)
    blocks = _blocks(n)
    held = blocks % 2 == 1
    data = model_data(rec, sc, step=step, length=length, fit_w=(~held).astype(float))
    y = np.asarray(data.y)[:n]
    sigma = noise_std(rec.y) / sc.y_half
    sigma2 = max(sigma**2, 1e-12)

    def run_fit(theta0, names):
        g = jnp.asarray(_effects.group_mask(names))
        res = _effects.fit(jnp.asarray(theta0), g, data)
        pred = np.asarray(_effects.predict_jit(res.theta, g, data))[:n]
        return np.asarray(res.theta), pred

    theta, pred = run_fit(_base_start(data, n), [])
    theta_base, pred_base = theta, pred
    named, rounds = [], []
    n_held = int(held.sum())
    start = _effects.initial_params()
    while len(named) < max_effects:
        cur_mse = float(np.mean((pred[held] - y[held]) ** 2))
        scores = {}
        for c in candidates:
            if c in named:
                continue
            sl = _effects._sl(c)
            best_fit = None
            starts = []
            for extra in _EXTRA_STARTS.get(c, [None]):
                th0 = theta.copy()
                th0[sl] = start[sl] if extra is None else extra
                starts.append(th0)
            if c == "delay":
                starts = _delay_starts(theta, [*named, c], data, y, ~held, n)
            for th0 in starts:
                th_c, pred_c = run_fit(th0, [*named, c])
                sse = float(np.sum(((pred_c - y) ** 2)[~held]))
                if best_fit is None or sse < best_fit[0]:
                    best_fit = (sse, th_c, pred_c)
            _, th_c, pred_c = best_fit
            gain, t = _score(pred, pred_c, y, held, blocks)
            penal = gain - PARAM_PENALTY * sigma2 * _effects.n_effect_params(c) / n_held
            scores[c] = dict(
                heldout_rmse=float(np.sqrt(np.mean((pred_c[held] - y[held]) ** 2))) * sc.y_half,
                gain=gain, score=penal / sigma2, t=t, theta=th_c, pred=pred_c,
            )
        if not scores:
            break
        best = max(scores, key=lambda k: scores[k]["score"])
        b = scores[best]
        ok = b["score"] > MIN_GAIN_NOISE and b["gain"] > MIN_GAIN_REL * cur_mse
        rounds.append(
            dict(
                current_heldout_rmse=float(np.sqrt(cur_mse)) * sc.y_half,
                candidates={k: {kk: v[kk] for kk in ("heldout_rmse", "score", "t")} for k, v in scores.items()},
                best=best, named=bool(ok),
            )
        )
        if not ok:
            break
        named.append(best)
        theta, pred = b["theta"], b["pred"]
    named, theta, pred, pruned = _prune(named, theta, pred, run_fit, y, held, sigma2, n_held)
    # Final fits on every sample, warm-started from the search.
    data_all = model_data(rec, sc, step=step, length=length)
    g_b, g_f = (jnp.asarray(_effects.group_mask(x)) for x in ([], named))
    theta_final = theta
    if refit:
        theta_base = np.asarray(_effects.fit(jnp.asarray(theta_base), g_b, data_all).theta)
        theta_final = np.asarray(_effects.fit(jnp.asarray(theta), g_f, data_all).theta)
    return dict(
        effects=named, pruned=pruned, rounds=rounds, theta_base=theta_base, theta_final=theta_final,
        scaling=sc, noise_std=sigma * sc.y_half, step=step,
        heldout_rmse_base=float(np.sqrt(np.mean((pred_base[held] - y[held]) ** 2))) * sc.y_half,
        heldout_rmse_final=float(np.sqrt(np.mean((pred[held] - y[held]) ** 2))) * sc.y_half,
    )


def evaluate(rec: Record, sc: Scaling, theta, names, *, transferable_only=False):
    """Run a fitted model on a record at full rate; returns (prediction in data units, RMSE).

    **Arguments:**

    - `rec`: the record; `sc`: the identification record's `Scaling`.
    - `theta`, `names`: the fitted parameters and the effects switched on.
    - `transferable_only`: for another record, switch off the effects tied to the identification
      record itself (its initial states and its drift over time).

    **Returns:** `(prediction, rmse)`.
    """
    import jax.numpy as jnp

    if transferable_only:
        names = [e for e in names if e not in ("initial_state", "offset_drift")]
    data = model_data(rec, sc, length=_bucket(rec.n_samples))
    g = jnp.asarray(_effects.group_mask(names))
    pred = np.asarray(_effects.predict_jit(jnp.asarray(theta), g, data))[: rec.n_samples]
    pred = pred * sc.y_half + sc.y_mid
    return pred, float(np.sqrt(np.mean((pred - rec.y) ** 2)))


def diagnose(rec: Record, validation: Record | None = None, **kwargs) -> dict:
    """The whole workflow on one record: locate, name, and show the gap shrink.

    **Arguments:**

    - `rec`: the identification record.
    - `validation`: an optional second record of the same device, run through both models.
    - `**kwargs`: passed to `search`.

    **Returns:** a JSON-ready dict with `effects`, `baseline_rmse`, `final_rmse`,
    `noise_std_estimate`, `candidates`, `rounds`, `where`, `heldout` and, with a validation record,
    `validation` (`baseline_rmse`, `final_rmse`); arrays for plotting are under `_arrays`.
    """
    s = search(rec, **kwargs)
    sc, named = s["scaling"], s["effects"]
    pred_b, rmse_b = evaluate(rec, sc, s["theta_base"], [])
    pred_f, rmse_f = evaluate(rec, sc, s["theta_final"], named)
    first = s["rounds"][0]["candidates"] if s["rounds"] else {}
    out = dict(
        effects=named,
        baseline_rmse=rmse_b,
        final_rmse=rmse_f,
        noise_std_estimate=s["noise_std"],
        candidates={k: dict(v) for k, v in first.items()},
        rounds=s["rounds"],
        pruned=s["pruned"],
        heldout=dict(baseline_rmse=s["heldout_rmse_base"], final_rmse=s["heldout_rmse_final"]),
        n_samples=rec.n_samples,
        search_step=s["step"],
        where=_locate.locate(rec.t, rec.u, rec.y, pred_b, s["noise_std"]),
    )
    arrays = dict(t=rec.t, u=rec.u, y=rec.y, base=pred_b, final=pred_f)
    if validation is not None:
        check_record(validation)
        vb, rb = evaluate(validation, sc, s["theta_base"], [], transferable_only=True)
        vf, rf = evaluate(validation, sc, s["theta_final"], named, transferable_only=True)
        out["validation"] = dict(
            baseline_rmse=rb, final_rmse=rf, noise_std_estimate=noise_std(validation.y),
            effects_used=[e for e in named if e not in ("initial_state", "offset_drift")],
        )
        arrays.update(val_t=validation.t, val_u=validation.u, val_y=validation.y, val_base=vb, val_final=vf)
    out["_arrays"] = arrays
    return out
