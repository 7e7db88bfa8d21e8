"""Input design: a slew-limited input that maximises the guaranteed PE margin of a play bank.

Once the plays are wiped out, every play that moves on a monotone stretch moves with the input,
and they start in the order of their thresholds (the play states satisfy |x_i − x_j| <= r_j − r_i),
so the event rows of Theorem 2 (`docs/excitation_condition.md`) are prefixes p_i = (1, ..., 1,
0, ..., 0) of i + 1 ones. A *half-cycle of level m* leaves a turning point where every play sits
on its envelope and travels q_m = 2 r_{m+1} (the last level: 2 A, from −A to A): play i starts
after 2 r_i, so it moves the prefix p_i over g_i = 2 (r_{i+1} − r_i) for i <= m (the last
segment of the full swing: 2 A − 2 r_{n−1}). Its increments add Σ_{i<=m} g_i² p_i p_iᵀ to DᵀD in
Theorem 4. The half-cycle passes a sample exactly where each play starts (so no two plays start
inside one sample, however close their thresholds) and otherwise moves at the slew limit S:
segment i takes ⌈g_i / (S dt)⌉ samples, the level c_m samples in all. With a share y_m of the
samples per period spent on level m, the information per sample is

    Pᵀ diag(a) P,   a_i = g_i² Σ_{m>=i} y_m / c_m,   P the lower-triangular ones matrix,

whose smallest eigenvalue is concave in y: the design maximises it over the simplex by entropic
mirror ascent, rounds the shares to whole up-and-down pairs per period, and keeps the number of
periods per window whose realised input has the largest margin (`pe_margin`, the smallest over
windows). Every level starts and ends at −A, so every half-cycle starts with the plays on their
envelopes and the rows are the prefixes above (up to rounding where a play starts).
"""

import math
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from .._checks import is_whole
from .._operators.play import play
from .exact_condition import pe_margin

_PERIODS_PER_WINDOW = (1, 2, 3, 4, 6, 8)


class InputDesign(NamedTuple):
    """What [`design_input`][] returns.

    **Fields:** `u` (N,) the designed input; `margin` the smallest `pe_margin` over its windows
    (every window // 10 samples, from zero initial play states); `margins` (windows,) each
    window's; `levels` (n,) the half-cycles' peak-to-peak travel q_m; `pairs` (n,) up-and-down
    pairs of each level per period; `period` samples per period; `shares` (n,) the optimal share
    of samples per level (before rounding); `ideal_margin` the margin the shares promise per
    window (the relaxed optimum, before rounding and window alignment); `slew` the slew limit S
    per second.
    """

    u: np.ndarray
    margin: float
    margins: np.ndarray
    levels: np.ndarray
    pairs: np.ndarray
    period: int
    shares: np.ndarray
    ideal_margin: float
    slew: float


def _gains(r, amplitude):
    upper = np.append(r[1:], amplitude)
    return 2 * (upper - r), 2 * upper


def _waypoints(r, m, level):
    """Travel from the turning point at which play i starts, i <= m, and the level's end."""
    return np.unique(np.append(2 * r[: m + 1], level))


def _costs(r, levels, step):
    """Samples per half-cycle of each level: one segment per waypoint, each at the slew limit."""
    return np.array(
        [
            sum(max(1, math.ceil(d / step - 1e-9)) for d in np.diff(np.append(0.0, _waypoints(r, m, q))) if d > 0)
            for m, q in enumerate(levels)
        ]
    )


def _information(shares, gains, costs):
    a = gains**2 * np.cumsum((shares / costs)[::-1])[::-1]
    P = np.tril(np.ones((a.size, a.size)))
    return P.T @ (a[:, None] * P)


def optimal_shares(r, amplitude, step, *, iterations: int = 3000):
    """The shares of samples per level that maximise λ_min of the information per sample.

    **Arguments:** `r` (n,) increasing thresholds >= 0; `amplitude` A > r_max; `step` the
    largest move per sample (slew limit × dt).

    **Returns:** `(shares, value)`: shares (n,) >= 0 summing to 1, and λ_min at them.
    """
    r = np.asarray(r, float)
    gains, levels = _gains(r, float(amplitude))
    costs = _costs(r, levels, step)
    n = r.size
    # The subgradient of λ_min at share m is vᵀ M_m v / q_m with v its eigenvector; mirror ascent
    # on the simplex with steps 1/√k, keeping the best point seen (λ_min is not smooth where its
    # eigenvalue is repeated, which is where the optimum usually lies).
    y = np.full(n, 1.0 / n)
    best, best_y = -np.inf, y
    P = np.tril(np.ones((n, n)))
    for k in range(1, iterations + 1):
        lam, V = np.linalg.eigh(_information(y, gains, costs))
        if lam[0] > best:
            best, best_y = lam[0], y
        proj = (P @ V[:, 0]) ** 2 * gains**2  # (p_i · v)² g_i²
        grad = np.cumsum(proj) / costs  # level m gets the rows i <= m
        step = 1.0 / (math.sqrt(k) * max(float(np.max(np.abs(grad))), np.finfo(float).tiny))
        y = y * np.exp(step * (grad - grad.max()))
        y = y / y.sum()
    return best_y, float(best)


def _travel(points, step):
    """Samples along straight moves between points (each hit exactly), at most `step` per sample."""
    out = [np.asarray([points[0]], float)]
    for a, b in zip(points[:-1], points[1:]):
        k = max(1, math.ceil(abs(b - a) / step - 1e-9))
        seg = a + (b - a) * np.arange(1, k + 1) / k
        seg[-1] = b  # the point itself, not a rounding of it
        out.append(seg)
    return np.concatenate(out)


def _realise(r, pairs, levels, amplitude, step, n_samples):
    """The input: 0 → A → −A (wipes out any initial state), then periods of levels, largest first.

    A level rises from −A through −A + 2 r_i (where play i starts) and falls back through
    −A + q_m − 2 r_i (where it starts again the other way)."""
    period = [-amplitude]
    for m in np.argsort(-levels, kind="stable"):
        way = _waypoints(r, m, levels[m])
        for _ in range(int(pairs[m])):
            period += list(-amplitude + way) + list(-amplitude + levels[m] - way)
    period = [x for i, x in enumerate(period) if i == 0 or x != period[i - 1]]
    one = _travel(period, step)[1:]
    head = _travel([0.0, amplitude, -amplitude], step)
    reps = -(-(n_samples - head.size) // max(one.size, 1)) if n_samples > head.size else 0
    return np.concatenate([head, np.tile(one, reps)])[:n_samples], one.size


def _check(r, amplitude, n_samples, window, dt, slew):
    r = np.asarray(r, float)
    if r.ndim != 1 or r.size < 1 or not np.all(np.isfinite(r)) or r[0] < 0 or np.any(np.diff(r) <= 0):
        raise ValueError(f"`r` must be finite thresholds >= 0, strictly increasing, got {r}")
    for name, v in (("amplitude", amplitude), ("dt", dt), ("slew", slew)):
        if isinstance(v, bool) or not isinstance(v, int | float | np.floating) or not (math.isfinite(v) and v > 0):
            raise ValueError(f"`{name}` must be a positive finite number, got {v!r}")
    if amplitude > 1e150:
        raise ValueError(
            f"`amplitude` ({amplitude:g}) is too large: the design squares swings of 2 A; "
            "express the input in larger units"
        )
    if amplitude <= r[-1]:
        raise ValueError(
            f"`amplitude` ({amplitude:g}) must exceed the largest threshold ({r[-1]:g}): a swing of "
            "less than 2 r_max never moves that play"
        )
    if not is_whole(n_samples) or n_samples < 2:
        raise ValueError(f"`n_samples` must be a whole number >= 2, got {n_samples!r}")
    if not is_whole(window) or not 2 <= window <= n_samples:
        raise ValueError(f"`window` must be a whole number of samples in [2, n_samples], got {window!r}")
    full = math.ceil(2 * amplitude / (slew * dt))
    if full > window:
        raise ValueError(
            f"one swing from -{amplitude:g} to {amplitude:g} at slew {slew:g}/s takes {full} samples, "
            f"longer than the window ({window}); allow a faster slew or a longer window"
        )
    return r, int(n_samples), int(window)


def design_input(r, *, amplitude, n_samples, window, dt, slew) -> InputDesign:
    """Design an input of `n_samples` that maximises the guaranteed PE margin of plays `r`.

    The input stays within ±`amplitude`, moves at most `slew` per second, and is built from
    half-cycles that start at −A (see the module's docstring for the design problem, which is
    concave, and its solution). Among 1, 2, 3, 4, 6 and 8 periods per window it keeps the one
    whose realised input has the largest smallest-window margin.

    **Arguments:**

    - `r`: thresholds (n,), >= 0 and strictly increasing.
    - `amplitude`: the limit A on |u|, > max r.
    - `n_samples`, `window`: the record's and a PE window's length in samples.
    - `dt`: the sampling step in seconds; `slew`: the largest |du/dt| (units per second).

    **Returns:** an [`InputDesign`][]. Bad values raise `ValueError` naming the argument.
    """
    r, n_samples, window = _check(r, amplitude, n_samples, window, dt, slew)
    amplitude, step = float(amplitude), float(slew) * float(dt)
    shares, value = optimal_shares(r, amplitude, step)
    _, levels = _gains(r, amplitude)
    costs = _costs(r, levels, step)
    best = None
    for p in _PERIODS_PER_WINDOW:
        pairs = np.floor(shares * (window / p) / (2 * costs) + 0.5).astype(int)
        # The full swing is the only level that moves the last play: without it no window is PE.
        pairs[-1] = max(pairs[-1], 1)
        u, period = _realise(r, pairs, levels, amplitude, step, n_samples)
        if period > window:
            continue
        H = play(jnp.asarray(u), jnp.asarray(r, u.dtype))
        margins = np.asarray(pe_margin(H, jnp.asarray(u), jnp.asarray(r, u.dtype), window, stride=max(1, window // 10)))
        if best is None or margins.min() > best[0].min():
            best = (margins, u, pairs, period)
    if best is None:
        raise ValueError(f"no period of the design fits the window ({window} samples); lengthen it")
    margins, u, pairs, period = best
    # Per window: L samples worth `value` of λ_min(DᵀD) each, over 4 L.
    ideal = value / 4
    return InputDesign(u, float(margins.min()), margins, levels, pairs, period, shares, ideal, float(slew))
