"""The diagnosis models as regressors: y = X(q) w, fitted by variable projection.

Every model the diagnosis compares is linear in its coefficients once the effects' few nonlinear
parameters q (a delay, a time constant, a rate exponent, ...) are fixed: the columns X are play
outputs on a fixed, dense threshold grid (`basis`) plus an offset column, passed through the
signal chain of the effects switched on (`effect.py` describes the stages), with the output
terms as further columns. For fixed q the coefficients are a (sign-constrained) linear
least-squares solution, so every candidate is fitted exactly and fast, and q is chosen on a grid
by the error on held-out blocks, which avoids the local minima a gradient search meets in delays
and dynamics. Output terms that depend on the hysteresis output v = X w are rebuilt from the
previous fit (`fit`). Time constants and the delay are physical (seconds), so a model chosen on a
sub-sampled record runs unchanged at the full rate.

A configuration `cfg` is a dict effect name -> grid value.
"""

from typing import NamedTuple

import numpy as np
from scipy import linalg as _linalg
from scipy import optimize as _optimize

from .basis import N_PLAYS, THRESHOLDS, plays
from .effects import EFFECT, chain
from .output_map import OutputMapEffect

RIDGE = 1e-6
# At most this many fits of the output map, each about the centre and half-range that the one
# before found (`fit`).
MAP_PASSES = 4


def play_inputs(p, cfg):
    """The plays' input g and thresholds, (n,) or time-varying, for a configuration.

    Both are on the samples the plays run on (`p.play_u`, which `p.keep` reduces to the
    record's samples).
    """
    g, r = p.play_u, THRESHOLDS
    for e in chain(cfg):
        g = e.input_map(cfg[e.name], g)
    for e in chain(cfg):
        r = e.thresholds(cfg[e.name], p, r)
    return g, r


def play_columns(p, cfg):
    """The play part of X (T, n) for a configuration."""
    if not any(e.changes_plays(cfg[e.name]) for e in chain(cfg)):
        return p.plain_plays()
    g, r = play_inputs(p, cfg)
    x0 = np.full(N_PLAYS, g[0])
    for e in chain(cfg):
        x0 = e.initial_states(cfg[e.name], g[0], x0)
    return plays(g, r, x0[None], p.keep)[0]


def linear_part(p, cfg, play_cols=None):
    """X before the output terms: plays, offset and play terms, through the effects' linear filters."""
    H = play_columns(p, cfg) if play_cols is None else play_cols
    terms = [e.play_terms(cfg[e.name], H) for e in chain(cfg) if e.n_play_terms(cfg[e.name])]
    X = np.column_stack([H, np.ones(len(H)), *terms])
    for e in chain(cfg):
        X = e.linear(cfg[e.name], X, p.dt)
    return X


def _slices(cfg, count, start) -> dict:
    out = {}
    for e in chain(cfg):
        k = count(e, cfg[e.name])
        if k:
            out[e.name] = slice(start, start + k)
            start += k
    return out


def n_linear(cfg) -> int:
    """How many columns `linear_part` has: plays, offset and play terms."""
    return N_PLAYS + 1 + sum(e.n_play_terms(cfg[e.name]) for e in chain(cfg))


def play_term_slices(cfg) -> dict:
    """Where each effect's play-term coefficients sit in the coefficient vector."""
    return _slices(cfg, lambda e, q: e.n_play_terms(q), N_PLAYS + 1)


def output_slices(cfg) -> dict:
    """Where each effect's output coefficients sit in the coefficient vector."""
    return _slices(cfg, lambda e, q: e.n_columns(q), n_linear(cfg))


def coefficient_slices(cfg) -> dict:
    """Each effect's own coefficients (play terms or output terms) in the coefficient vector."""
    return {**play_term_slices(cfg), **output_slices(cfg)}


def output_terms(p, cfg, v, norm, drive=None):
    """The output-term columns at the hysteresis output `v`, in chain order.

    `norm` = (centre, half-range) scales v for the output map; it is fixed by the fit on
    the identification record, so that a validation record sees the same map. `drive`
    is what slow terms follow (default v; see `drive_of`).
    """
    drive = v if drive is None else drive
    cols = [e.columns(cfg[e.name], p, v, drive, norm) for e in chain(cfg) if e.n_columns(cfg[e.name])]
    return np.column_stack(cols) if cols else np.zeros((len(v), 0))


def drive_of(p, cfg, v0, w_v, norm):
    """What slow output terms follow, from the previous coefficients `w_v`: v0 plus the terms
    before them (the output map), when `w_v` has output coefficients."""
    drive = v0
    if len(w_v) <= n_linear(cfg):
        return drive
    for name, sl in output_slices(cfg).items():
        drive = EFFECT[name].drive(cfg[name], drive, v0, norm, w_v[sl])
    return drive


def positive_mask(cfg, n_cols, signed=False):
    """Which columns have a coefficient >= 0: the plays' weights and positive output terms.

    Positive play weights are the physical PI model of a counterclockwise loop (every cumulative
    weight positive, hence an invertible operator); `signed` frees them, for a loop that runs
    clockwise (`Prepared.signed`). An effect marks its own output terms positive (creep's
    lags of the output); play terms are signed.
    """
    pos = np.zeros(n_cols, bool)
    pos[:N_PLAYS] = not signed
    if n_cols > n_linear(cfg):
        for name, sl in output_slices(cfg).items():
            pos[sl] = EFFECT[name].positive_terms(cfg[name])
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


def lstsq(A, y, pos=None):
    """Least squares with the coefficients in `pos` (default: the first N_PLAYS columns) kept >= 0."""
    pos = positive_mask({}, A.shape[1]) if pos is None else pos
    return _solve(A.T @ A, A.T @ y, _scale(A), pos)


class Fit(NamedTuple):
    """A fitted configuration.

    `A` (T, q) is the design at the solution and `target` (T,) what `A @ w` fits: the data,
    plus, with an output term nonlinear in v, the offset of its linearisation (Gauss-Newton).
    `w_v` are the previous coefficients, which built the slow terms and the linearisation,
    `norm` the (centre, half-range) of the hysteresis output that scales the output map.
    """

    A: np.ndarray
    target: np.ndarray
    w: np.ndarray
    w_v: np.ndarray
    norm: tuple


def _slope(p, cfg, v0, w, norm):
    """d(output terms @ w)/dv at v0 for the terms nonlinear in v, or None."""
    g = None
    for name, sl in output_slices(cfg).items():
        s = EFFECT[name].slope(cfg[name], v0, norm, w[sl])
        if s is not None:
            g = s if g is None else g + s
    return g


def fit(p, cfg, *, X=None) -> Fit:
    """Fit the coefficients of one configuration by (sign-constrained) least squares.

    The output terms depend on the hysteresis output v = X w. Terms linear in v (creep) are
    rebuilt from the previous fit (a fixed-point iteration, creep being small). A term nonlinear
    in v (the output map, y = v + P(v) a, bilinear in (w, a)) makes a fixed-point
    iteration stall short of the optimum, so it takes Gauss-Newton steps: around (w0, a0),
    y + g v0 = diag(1 + g) X w + P(v0) a with g = P'(v0) a0, a least-squares problem.

    **Arguments:** `p`, a prepared record; `cfg`; `X`, a precomputed `linear_part`.

    **Returns:** a `Fit`.
    """
    X = linear_part(p, cfg) if X is None else X
    px = X.shape[1]
    w0 = lstsq(X, p.y, positive_mask({}, px, p.signed))
    slices = output_slices(cfg)
    norm = _centre(X @ w0)
    if not slices:
        return Fit(X, p.y, w0, w0, norm)
    best = _output_terms_fit(p, cfg, X, w0, norm)
    if any(isinstance(EFFECT[n], OutputMapEffect) for n in slices):
        # The output map's terms are split by parity about the loop's centre and scaled by its
        # half-range, which the plain fit's output only approximates (an even part shifts it,
        # a saturation shrinks it): further passes take them about the centre and half-range
        # of the hysteresis output the last pass found.
        for _ in range(MAP_PASSES - 1):
            new = _centre(X @ best[1].w[:px])
            if np.allclose(new, best[1].norm, rtol=0, atol=0.01 * best[1].norm[1]):
                break
            again = _output_terms_fit(p, cfg, X, w0, new)
            if again[0] >= best[0]:
                break
            best = again
    return best[1]


def _output_terms_fit(p, cfg, X, w, norm) -> tuple[float, Fit]:
    """`fit`'s iterations for the output terms from the plain coefficients `w`, with the
    output map's normalisation `norm` fixed: (sum of squared errors, the fit); the error is
    only computed, and NaN otherwise, when a term is nonlinear in v."""
    px = X.shape[1]
    slices = output_slices(cfg)
    bilinear = any(EFFECT[n].bilinear for n in slices)
    iters = max(EFFECT[n].fit_iterations for n in slices)
    n_out = sum(s.stop - s.start for s in slices.values())
    pos = positive_mask(cfg, px + n_out, p.signed)
    best = None
    for i in range(iters):
        w_v = w
        v0 = X @ w_v[:px]
        # The slow terms' drive is fixed within an iteration: the predictions below reuse it.
        drive = drive_of(p, cfg, v0, w_v, norm)
        T = output_terms(p, cfg, v0, norm, drive)
        Xs, target = X, p.y
        g = _slope(p, cfg, v0, w, norm) if i > 0 else None
        if g is not None:
            Xs, target = (1 + g)[:, None] * X, p.y + g * v0
        A = np.column_stack([Xs, T])
        w = lstsq(A, target, pos)
        if not bilinear:  # the fixed-point iteration's last iterate
            best = (np.nan, Fit(A, target, w, w_v, norm))
            continue
        sse = float(np.sum((_predict(X, p, cfg, w, w_v, norm, drive) - p.y) ** 2))
        if best is not None and sse >= best[0]:
            # A full Gauss-Newton step can overshoot: it is shortened until the model improves
            # (backtracking), else the best model seen is kept.
            full, w0 = w, best[1].w
            for shrink in (0.5, 0.25, 0.125):
                w = w0 + shrink * (full - w0)
                sse = float(np.sum((_predict(X, p, cfg, w, w_v, norm, drive) - p.y) ** 2))
                if sse < best[0]:
                    break
            else:
                break
            # The linear problem whose solution the shortened step is, for the held-out score.
            target = target - A @ (full - w)
        best = (sse, Fit(A, target, w, w_v, norm))
    assert best is not None
    return best


def _centre(v):
    """(centre, half-range) of a hysteresis output."""
    return (0.5 * (v.max() + v.min()), max(0.5 * np.ptp(v), 1e-12))


def predict(p, cfg, w, w_v, norm):
    """The output of a fitted configuration on a (possibly different) record, normalised units.

    The model itself, y = v + sum_k T_k(v, drive(X w_v)) c_k with v = X w, not its linearisation.
    """
    return _predict(linear_part(p, cfg), p, cfg, w, w_v, norm)


def _predict(X, p, cfg, w, w_v, norm, drive=None):
    """`predict` from the linear part `X`; `drive`, when given, is `drive_of` at X w_v."""
    px = X.shape[1]
    v = X @ w[:px]
    if drive is None:
        drive = drive_of(p, cfg, X @ w_v[:px], w_v, norm)
    T = output_terms(p, cfg, v, norm, drive)
    return v + T @ w[px:]


def without(cfg, names, *coefs):
    """A configuration and coefficient vectors with the effects in `names` left out.

    A vector too short to hold an effect's output coefficients (the plays-only start of `fit`)
    is returned as it is.
    """
    slices = coefficient_slices(cfg)
    out = []
    for w in coefs:
        w = np.asarray(w)
        drop = np.zeros(len(w), bool)
        for n in names:
            if n in slices and slices[n].stop <= len(w):
                drop[slices[n]] = True
        out.append(w[~drop])
    return {k: v for k, v in cfg.items() if k not in names}, *out


def cv_mse(p, A, cfg=None, target=None):
    """Mean squared error on held-out blocks: each fold is fitted on the others and predicted.

    **Arguments:** `p` (with `folds`); `A` (T, q), the regressors; `cfg`, the configuration
    that built them (for the sign constraints); `target`, what A fits (default `p.y`).

    Samples of fold -1 (the record's first block: `scaling.prepared`) are always fitted, never
    held out.

    **Returns:** `(mse, errors)`, the errors (T,) each from the fit that did not see them (NaN on
    the samples always fitted); `mse` is their mean square.
    """
    y = p.y if target is None else target
    scale = _scale(A)
    pos = positive_mask(cfg or {}, A.shape[1], p.signed)
    G, b = A.T @ A, A.T @ y
    parts = [(p.folds == k) for k in np.unique(p.folds) if k >= 0]
    err = np.full(len(p.y), np.nan)
    for m in parts:
        err[m] = y[m] - A[m] @ _solve(G - A[m].T @ A[m], b - A[m].T @ y[m], scale, pos)
    return float(np.nanmean(err**2)), err
