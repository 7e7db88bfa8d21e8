"""The PI model and the seven effects it can be augmented with, as regressors.

Every model the diagnosis compares is y = X(q) w: the columns X are play outputs on a fixed, dense
threshold grid (plus an offset column), transformed by the effects switched on, and q holds the
effects' few nonlinear parameters (a delay, a time constant, a rate exponent, ...). For fixed q the
weights w are a linear least-squares solution (variable projection), so every candidate is fitted
exactly and fast, and q is chosen on a grid by the error on held-out blocks, which avoids the local
minima a gradient search meets in delays and dynamics. In normalised units (input and output
scaled to [-1, 1]) the model is

    g      = u + b u^2                                         (asymmetry: input envelope)
    r_j(t) = r_j (1 + beta rho^p)  or  r_j + gamma rho^p       (rate_dependence, rho = |du/dt|)
    X      = [plays_r(g) from states x0, 1]                    (initial_state: x0 left by a history)
    X      <- X(t - d)                                         (delay, fractional)
    X      <- H(s) X, H = 1/(tau s + 1) or w^2/(s^2 + 2 zeta w s + w^2)   (linear_dynamics)
    y      = X w + [v^2 .. v^5] a                              (asymmetry: output polynomial)
             + [lowpass_tau_k(v) - v] c                        (creep, slow modes)
             + [cos(k pi s)] d                                 (offset_drift, s = t / duration)

with v = X w the hysteresis output (the output-side terms are refreshed from v twice). Time
constants and the delay are physical (seconds), so a model chosen on a sub-sampled record runs
unchanged at the full rate.
"""

import functools
from typing import NamedTuple

import numpy as np
from scipy import linalg as _linalg
from scipy import optimize as _optimize
from scipy import signal as _signal

EFFECTS = (
    "initial_state",
    "delay",
    "linear_dynamics",
    "rate_dependence",
    "creep",
    "asymmetry",
    "offset_drift",
)
# Effects tied to the record they were found on (the unrecorded past before its first sample, a
# drift over its time axis): they explain that record but cannot carry over to another run of the
# device, so a model used on another record leaves them out. The others are functions of the input.
RECORD_SPECIFIC = ("initial_state", "offset_drift")
N_PLAYS = 16
THRESHOLDS = np.arange(N_PLAYS) / N_PLAYS
N_CREEP = 5  # creep modes, log-spaced from a third of the input's period to the record's length
N_DRIFT = 6
N_POLY = 4  # output polynomial terms v^2 .. v^5
POLY_RANGE = 1.5
RIDGE = 1e-6
# Parameters each effect adds: its linear coefficients plus its grid parameters.
N_PARAMS = {
    "initial_state": 2,
    "delay": 1,
    "linear_dynamics": 2,
    "rate_dependence": 2,
    "creep": N_CREEP,
    "asymmetry": N_POLY + 1,
    "offset_drift": N_DRIFT,
}


def plays(g, r, x0, keep=None):
    """Play outputs for several initial states at once.

    **Arguments:** `g` (T,), the (transformed) input; `r`, thresholds (n,) or time-varying (T, n);
    `x0` (C, n), C sets of initial states; `keep`, the sample positions to return (default all).

    **Returns:** (C, T, n), or (C, len(keep), n).
    """
    g = np.asarray(g, float)
    x = np.array(x0, float)
    rr = np.broadcast_to(np.asarray(r, float), (len(g), x.shape[-1]))
    lo, hi = g[:, None] - rr, g[:, None] + rr
    slot = np.full(len(g), -1)
    slot[np.arange(len(g)) if keep is None else np.asarray(keep)] = np.arange(len(g) if keep is None else len(keep))
    out = np.empty((len(g) if keep is None else len(keep), x.shape[0], x.shape[1]))
    for i in range(len(g)):
        np.maximum(x, lo[i], out=x)
        np.minimum(x, hi[i], out=x)
        if slot[i] >= 0:
            out[slot[i]] = x
    return out.transpose(1, 0, 2)


def history_states(u0, turns):
    """Play states left by an input history u0 -> turns[0] -> turns[1] ... -> u0, from rest at u0.

    **Arguments:** `u0`, the first input sample; `turns`, the turning points (normalised units).

    **Returns:** the states (n,) on the threshold grid.
    """
    x = np.full(N_PLAYS, float(u0))
    for a in [*turns, u0]:
        x = np.clip(x, a - THRESHOLDS, a + THRESHOLDS)
    return x


def delayed(X, d):
    """Columns of X delayed by d samples (fractional, linear interpolation; the start is held)."""
    if d <= 0:
        return X
    k, f = int(np.floor(d)), d - np.floor(d)
    idx = np.arange(len(X))
    a = X[np.clip(idx - k, 0, None)]
    b = X[np.clip(idx - k - 1, 0, None)]
    return (1 - f) * a + f * b


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


def lowpass(v, lam):
    """First-order low-pass y_t = lam y_{t-1} + (1 - lam) v_t, starting at v_0; `lam` (k,) -> (T, k)."""
    v = np.asarray(v, float)
    return np.column_stack(
        [_signal.lfilter([1 - a], [1.0, -a], v, zi=[a * v[0]])[0] for a in np.asarray(lam, float)]
    )


def turning_samples(u, step: int):
    """The samples of `u` the plays need to be exact at every `step`-th sample.

    A play's state at the end of a stretch of input depends on the stretch only through its
    suffix extrema: the samples above (or below) every later sample of the stretch. Any other
    sample lies between a later maximum and a later minimum, and the clamps at those later
    samples make the clamp at it irrelevant (the wiping-out property of the play). So the plays
    run on every `step`-th sample plus the suffix extrema of the stretches between them give the
    full-rate outputs at the kept samples exactly: no peak is missed, whatever the step. A
    noisy stretch of L samples has about 2 ln L suffix extrema.

    **Arguments:** `u` (T,), the full-rate input; `step`, the sub-sampling step.

    **Returns:** `(index, keep)`: the full-rate indices of the samples to run the plays on, in
    order, and the positions in that sequence of the samples 0, step, 2 step, ...
    """
    u = np.asarray(u, float)
    n_seg = (len(u) - 1) // step
    U = u[1 : 1 + n_seg * step].reshape(n_seg, step)
    rev = U[:, ::-1]
    # The max (min) over the samples after each one, within its stretch.
    after_max = np.concatenate([np.full((n_seg, 1), -np.inf), np.maximum.accumulate(rev, axis=1)[:, :-1]], axis=1)[:, ::-1]
    after_min = np.concatenate([np.full((n_seg, 1), np.inf), np.minimum.accumulate(rev, axis=1)[:, :-1]], axis=1)[:, ::-1]
    is_max, is_min = U > after_max, U < after_min
    kind = np.where(is_max & ~is_min, 1, np.where(is_min & ~is_max, -1, 0))
    kind[:, -1] = 0
    take = is_max | is_min
    take[:, -1] = True
    # Inside a run of suffix maxima (a falling stretch) or minima (a rising one) only the run's
    # ends matter: along a rising stretch the latest lower bound and the earliest upper bound of
    # the clamps dominate, so the samples in between change nothing.
    seg, pos = np.nonzero(take)
    k = kind[seg, pos]
    same_seg = seg[1:-1] == seg[:-2]
    inner = (k[1:-1] != 0) & same_seg & (seg[1:-1] == seg[2:]) & (k[:-2] == k[1:-1]) & (k[2:] == k[1:-1])
    drop = np.concatenate([[False], inner, [False]]) if len(k) > 2 else np.zeros(len(k), bool)
    index = np.concatenate([[0], 1 + seg[~drop] * step + pos[~drop]])
    keep = np.searchsorted(index, np.arange(0, n_seg * step + 1, step))
    return index, keep


class Prepared:
    """One record in normalised units, with the quantities every regressor needs.

    With `play_u`, `play_rho` and `keep` (from `turning_samples`), the record is a sub-sampled
    one whose plays run on the kept samples plus the turning samples between them, so that the
    play columns equal the full-rate plays at the kept samples.
    """

    def __init__(self, u, y, t, rate_scale, period, folds=None, *, play_u=None, play_rho=None, keep=None):
        self.u, self.y, self.t = (np.asarray(a, float) for a in (u, y, t))
        self.dt = float(np.median(np.diff(self.t)))
        self.s = (self.t - self.t[0]) / max(self.t[-1] - self.t[0], 1e-300)
        self.rho = np.abs(np.gradient(self.u, self.t)) / rate_scale
        self.period = period
        self.folds = folds
        self.play_u = self.u if play_u is None else np.asarray(play_u, float)
        self.play_rho = self.rho if play_rho is None else np.asarray(play_rho, float)
        self.keep = keep
        self._plain = None

    def plain_plays(self):
        if self._plain is None:
            self._plain = plays(self.play_u, THRESHOLDS, np.full((1, N_PLAYS), self.u[0]), self.keep)[0]
        return self._plain


def play_inputs(p: Prepared, cfg):
    """The plays' input g and thresholds, (n,) or time-varying, for a configuration.

    Both are on the samples the plays run on (`p.play_u`, which `p.keep` reduces to the
    record's samples).
    """
    g = p.play_u + (cfg.get("asymmetry") or 0.0) * p.play_u**2
    rate = cfg.get("rate_dependence")
    if rate is None:
        return g, THRESHOLDS
    form, k, e = rate
    rp = p.play_rho[:, None] ** e
    r = THRESHOLDS[None, :] * (1 + k * rp) if form == "scale" else THRESHOLDS[None, :] + k * rp
    return g, r


def play_columns(p: Prepared, cfg):
    """The play part of X (T, n) for a configuration (dict effect -> grid parameters)."""
    rate, env, turns = cfg.get("rate_dependence"), cfg.get("asymmetry"), cfg.get("initial_state")
    if rate is None and not env and turns is None:
        return p.plain_plays()
    g, r = play_inputs(p, cfg)
    x0 = np.full(N_PLAYS, g[0]) if turns is None else history_states(g[0], turns)
    return plays(g, r, x0[None], p.keep)[0]


def linear_part(p: Prepared, cfg, play_cols=None):
    """X before the output-side terms: plays and offset, then delay and dynamics."""
    H = play_columns(p, cfg) if play_cols is None else play_cols
    X = np.column_stack([H, np.ones(len(H))])
    if cfg.get("delay") is not None:
        X = delayed(X, cfg["delay"] / p.dt)
    if cfg.get("linear_dynamics") is not None:
        X = dynamics(X, cfg["linear_dynamics"], p.dt)
    return X


def _poly(v, norm):
    """Output polynomial columns [vc^2 .. vc^(N_POLY+1)] and their derivatives in v."""
    # Well beyond the range of the first fit, the polynomial is held (the model continues
    # linearly): a polynomial extrapolated far past the data diverges.
    raw = (v - norm[0]) / norm[1]
    vc = np.clip(raw, -POLY_RANGE, POLY_RANGE)
    pw = [np.ones_like(vc), vc]
    for _ in range(N_POLY):
        pw.append(pw[-1] * vc)
    cols = np.column_stack(pw[2:])
    der = np.column_stack([k * pw[k - 1] for k in range(2, 2 + N_POLY)]) / norm[1]
    return cols, der * (np.abs(raw) < POLY_RANGE)[:, None]


def output_terms(p: Prepared, cfg, v, norm, drive=None):
    """The columns driven by the hysteresis output v (asymmetry, creep) and by time (drift).

    `norm` = (centre, half-range) scales v for the output polynomial; it is fixed by the fit on
    the identification record, so that a validation record sees the same polynomial. `drive`
    is what creep follows (default v): the output after the polynomial, when there is one, since
    creep is a slow yield of the displacement itself.
    """
    drive = v if drive is None else drive
    cols = []
    if "asymmetry" in cfg:
        cols += list(_poly(v, norm)[0].T)
    if "creep" in cfg:
        taus = np.asarray(cfg["creep"])
        lp = lowpass(drive, np.exp(-p.dt / taus))
        cols += list((lp - drive[:, None]).T)
    if "offset_drift" in cfg:
        cols += [np.cos(k * np.pi * p.s) for k in range(1, N_DRIFT + 1)]
    return np.column_stack(cols) if cols else np.zeros((len(v), 0))


def positive_mask(cfg, n_cols):
    """Which columns have a coefficient >= 0: the plays' weights and the creep modes.

    Positive play weights are the physical PI model (every cumulative weight positive, hence an
    invertible operator). A creep mode's column is lowpass(v) - v, the output lagging the
    hysteresis output: a positive coefficient is an output that keeps moving after a change, in
    the direction of the change, which is what creep is.
    """
    pos = np.zeros(n_cols, bool)
    pos[:N_PLAYS] = True
    if "creep" in cfg and n_cols > N_PLAYS + 1:
        start = N_PLAYS + 1 + (N_POLY if "asymmetry" in cfg else 0)
        pos[start : start + len(cfg["creep"])] = True
    return pos


def _solve(G, b, scale, pos):
    """Least squares from the normal equations with the coefficients in `pos` kept >= 0.

    The sign constraints also keep the fit from trading large opposite weights between columns
    that are nearly equal on the fitted samples (a play the input barely moves and the offset),
    which held-out blocks would expose. The weak ridge makes the Cholesky factor exist when
    columns coincide. The constrained problem is solved on the factor: min |R w - d|, with
    R^T R = G and R^T d = b, in column-normalised units.
    """
    n = G.shape[0]
    Gs = G / np.outer(scale, scale)
    Gs = Gs + RIDGE * max(np.trace(Gs) / n, 1e-300) * np.eye(n)
    L = np.linalg.cholesky(Gs)
    d = _linalg.solve_triangular(L, b / scale, lower=True, check_finite=False)
    R = L.T
    free = ~pos
    z = _optimize.nnls(np.concatenate([R[:, pos], R[:, free], -R[:, free]], axis=1), d, maxiter=50 * n)[0]
    w = np.empty(n)
    k, f = int(pos.sum()), int(free.sum())
    w[pos] = z[:k]
    w[free] = z[k : k + f] - z[k + f :]
    return w / scale


def _scale(A):
    s = np.sqrt(np.mean(A * A, axis=0))
    return np.where(s > 1e-150, s, 1.0)


def _lstsq(A, y, pos=None):
    pos = positive_mask({}, A.shape[1]) if pos is None else pos
    return _solve(A.T @ A, A.T @ y, _scale(A), pos)


class Fit(NamedTuple):
    """A fitted configuration.

    `A` (T, q) is the design at the solution and `target` (T,) what `A @ w` fits: the data,
    plus, with an output polynomial, the offset of its linearisation (Gauss-Newton). `w_v` are
    the previous coefficients, which built the creep columns and the linearisation, `norm`
    the (centre, half-range) of the hysteresis output that scales the polynomial.
    """

    A: np.ndarray
    target: np.ndarray
    w: np.ndarray
    w_v: np.ndarray
    norm: tuple


def fit(p: Prepared, cfg, *, X=None) -> Fit:
    """Fit the coefficients of one configuration by (sign-constrained) least squares.

    The output-side columns depend on the hysteresis output v = X w. Creep columns are linear in
    v and are rebuilt from the previous fit (a fixed-point iteration, creep being small). The
    output polynomial y = v + P(v) a is bilinear in (w, a), where a fixed-point iteration stalls
    short of the optimum for a strong nonlinearity, so it takes Gauss-Newton steps: around
    (w0, a0), y + g v0 = diag(1 + g) X w + P(v0) a with g = P'(v0) a0, a least-squares problem.

    **Arguments:** `p`; `cfg`; `X`, a precomputed `linear_part`.

    **Returns:** a `Fit`.
    """
    X = linear_part(p, cfg) if X is None else X
    px = X.shape[1]
    w = w_v = _lstsq(X, p.y)
    v = X @ w
    norm = (0.5 * (v.max() + v.min()), max(0.5 * np.ptp(v), 1e-12))
    A, target = X, p.y
    if any(k in cfg for k in ("asymmetry", "creep", "offset_drift")):
        asym = "asymmetry" in cfg
        iters = 5 if asym else 2 if "creep" in cfg else 1
        n_out = (N_POLY if asym else 0) + len(cfg.get("creep", ())) + ("offset_drift" in cfg) * N_DRIFT
        pos = positive_mask(cfg, px + n_out)
        best = None
        for i in range(iters):
            w_v = w
            v0 = X @ w_v[:px]
            T = output_terms(p, cfg, v0, norm, _drive(cfg, v0, w_v, norm))
            Xs, target = X, p.y
            if asym and i > 0:
                g = _poly(v0, norm)[1] @ w[px : px + N_POLY]
                Xs, target = (1 + g)[:, None] * X, p.y + g * v0
            A = np.column_stack([Xs, T])
            w = _lstsq(A, target, pos)
            if asym:
                # Gauss-Newton without a line search can overshoot: keep the best model seen.
                sse = float(np.sum((_predict(X, p, cfg, w, w_v, norm) - p.y) ** 2))
                if best is not None and sse >= best[0]:
                    break
                best = (sse, Fit(A, target, w, w_v, norm))
        if best is not None:
            return best[1]
    return Fit(A, target, w, w_v, norm)


def _drive(cfg, v0, w_v, norm):
    """The creep's drive from the previous coefficients: v0 plus its output polynomial."""
    if "asymmetry" in cfg and len(w_v) > N_PLAYS + 1:
        return v0 + _poly(v0, norm)[0] @ w_v[N_PLAYS + 1 : N_PLAYS + 1 + N_POLY]
    return v0


def predict(p: Prepared, cfg, w, w_v, norm):
    """The output of a fitted configuration on a (possibly different) record, normalised units.

    The model itself, y = v + P(v) a + creep(X w_v) c + drift d with v = X w, not its
    linearisation.
    """
    return _predict(linear_part(p, cfg), p, cfg, w, w_v, norm)


def _predict(X, p, cfg, w, w_v, norm):
    px = X.shape[1]
    v = X @ w[:px]
    v0 = X @ w_v[:px]
    T = output_terms(p, cfg, v0, norm, _drive(cfg, v0, w_v, norm))
    if "asymmetry" in cfg:
        T[:, :N_POLY] = _poly(v, norm)[0]
    return v + T @ w[px:]


def cv_mse(p: Prepared, A, cfg=None, target=None):
    """Mean squared error on held-out blocks: each fold is fitted on the others and predicted.

    **Arguments:** `p` (with `folds`); `A` (T, q), the regressors; `cfg`, the configuration
    that built them (for the sign constraints); `target`, what A fits (default `p.y`).

    **Returns:** `(mse, errors)`, the errors (T,) each from the fit that did not see them.
    """
    y = p.y if target is None else target
    scale = _scale(A)
    pos = positive_mask(cfg or {}, A.shape[1])
    parts = [(p.folds == k) for k in np.unique(p.folds)]
    grams = [(A[m].T @ A[m], A[m].T @ y[m]) for m in parts]
    G, b = sum(g for g, _ in grams), sum(v for _, v in grams)
    err = np.empty(len(p.y))
    for m, (Gk, bk) in zip(parts, grams):
        err[m] = y[m] - A[m] @ _solve(G - Gk, b - bk, scale, pos)
    return float(np.mean(err**2)), err


def grid(effect, p: Prepared):
    """The grid of nonlinear parameters for an effect (normalised input, physical time)."""
    if effect == "initial_state":
        u0 = p.u[0]
        one = [(u0 + a,) for a in np.linspace(-2.5, 2.5, 41) if abs(a) > 1e-9]
        lv = np.linspace(-2.5, 2.5, 11)
        two = [(u0 + a, u0 + b) for a in lv for b in lv if a * b < 0 and abs(b) < abs(a)]
        seen, out = set(), []
        for turns in one + two:
            key = tuple(np.round(history_states(u0, turns), 9))
            if key not in seen and np.any(np.abs(np.array(key) - u0) > 1e-9):
                seen.add(key)
                out.append(turns)
        return out
    if effect == "delay":
        top = max(64.0, 0.1 * p.period / p.dt)
        return list(np.geomspace(0.25, top, 36) * p.dt)
    if effect == "linear_dynamics":
        taus = np.geomspace(0.3 * p.dt, 0.5 * p.period, 20)
        first = [("first", tau) for tau in taus]
        second = [("second", 1 / tau, z) for tau in taus[::2] for z in (0.2, 0.35, 0.5, 0.7, 1.0)]
        return first + second
    if effect == "rate_dependence":
        return [("scale", k, e) for k in (0.1, 0.25, 0.5, 1.0, 2.0, 4.0) for e in (0.5, 1.0)] + [
            ("add", k, e) for k in (0.01, 0.025, 0.05, 0.1, 0.2, 0.4) for e in (0.5, 1.0)
        ]
    if effect == "asymmetry":
        return [0.0, -0.4, -0.2, 0.2, 0.4]
    if effect == "creep":
        duration = p.t[-1] - p.t[0]
        return [tuple(np.geomspace(min(0.1 * p.period, duration / 10), duration, N_CREEP))]
    return [True]


def neighbours(effect, q, level):
    """Values around a grid point, for a local refinement (finer with each `level`)."""
    f = 2.0 ** (0.5 ** (level + 2))  # 1.19, 1.09, 1.04: below the grids' spacing
    if effect == "delay":
        return [q / f, q * f]
    if effect == "linear_dynamics":
        if q[0] == "first":
            return [("first", q[1] / f), ("first", q[1] * f)]
        return [("second", q[1] / f, q[2]), ("second", q[1] * f, q[2]),
                ("second", q[1], q[2] / f), ("second", q[1], min(q[2] * f, 1.5))]
    if effect == "rate_dependence":
        return [(q[0], q[1] / f**2, q[2]), (q[0], q[1] * f**2, q[2])]
    if effect == "asymmetry":
        step = 0.1 * 0.5**level
        return [q - step, q + step]
    return []
