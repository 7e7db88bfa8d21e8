"""Where a fitted creep's time constants may lie: ordered, apart, and not faster than the input.

A creep lag is told apart from the plays by how it lags the input. A lag much faster than the
input moves it is the input minus τ times its rate, plus terms of order (ωτ)²: its weight c and
its time constant then enter the output only as c + w_1 (with the first play's weight) and c·τ,
so the record pins down neither c nor τ (the fit of a fast lag on the Aye & Ang piezo record
puts τ at 0.03 s ± 0.05 and its weight at 11 ± 21). Two lags whose time constants are close act
as one lag plus a narrow band-pass whose weight is as loose. The fit therefore parameterises the
lags' log time constants (in samples) as

    log τ_k = b_k + Σ_{j<=k} θ_j²,      b_k = log τ_min + k log ρ,

which keeps them ordered, each at least `LAG_RATIO` (ρ = √10, half a decade) times the one before,
and the fastest at least τ_min, for every value of θ. (Squares rather than softplus: a
lag that the data push onto its bound sits at θ = 0, a point the solver reaches, where a softplus
would send θ towards -∞ and the solver would run out of steps.) τ_min is
[`shortest_time_constant`][]: a quarter of 1/ω, ω the input's mean reversal frequency, so that at
the rate the input reverses a lag keeps ωτ ≥ 1/4 (and at least `MIN_SAMPLES` samples). Slow lags
are not bounded above: one slower than the record looks like an offset, and the covariance (its
standard error against its value) names it undetermined.
"""

import jax.numpy as jnp
import numpy as np
from jax import lax

from .._operators.play import play

LAG_RATIO = float(np.sqrt(10.0))
MIN_SAMPLES = 10.0
# The fraction of a reversal's amplitude, relative to the input's range, that counts it.
REVERSAL = 0.1
# ωτ at the floor, ω the input's mean reversal frequency (in radians per sample).
FLOOR_OMEGA_TAU = 0.25


def reversals(u, fraction: float = REVERSAL) -> int:
    """How many times `u` reverses by at least `fraction` of its range.

    A play of threshold r = fraction·range/2 moves only when the input pushes it, and turns only
    after the input has come back by 2r: the sign changes of its output's steps count the
    reversals at least that large, with no smoothing and no noise threshold to tune.

    **Arguments:** `u` (T,), the input; `fraction` in (0, 1).

    **Returns:** the number of reversals (0 for a monotone or constant input).
    """
    u = np.asarray(u, np.float64)
    span = float(np.ptp(u)) if u.size else 0.0
    if u.size < 3 or span == 0.0:
        return 0
    x = np.asarray(play(u, 0.5 * fraction * span, u[0], method="auto"))
    steps = np.diff(x)
    moves = np.sign(steps[steps != 0])
    return int(np.count_nonzero(moves[1:] != moves[:-1]))


def shortest_time_constant(u, dt: float = 1.0, mask=None, *, sample_dt: float | None = None) -> float:
    """The fastest creep time constant a fit on `u` allows (see the module notes).

    With n reversals over the D samples from the first fitted sample to the last, the input's
    mean reversal frequency is ω = π n / D radians per sample, and τ_min = `FLOOR_OMEGA_TAU`/ω
    samples, at least `MIN_SAMPLES`. An input that never reverses counts as reversing once.

    **Arguments:** `u` (T,); `dt`, the sampling interval; `mask` (T,) or None, 1 on the fitted
    samples.

    `sample_dt`: for a `u` sub-sampled from a record sampled every `sample_dt`, the floor counts
    that record's samples (default `dt`).

    **Returns:** τ_min in the units of `dt`.
    """
    floor = MIN_SAMPLES * (dt if sample_dt is None else sample_dt)
    u = np.asarray(u, np.float64)
    used = np.arange(u.size) if mask is None else np.flatnonzero(np.asarray(mask) > 0)
    if used.size == 0:
        return floor
    first, last = int(used[0]), int(used[-1])
    n = max(reversals(u[first : last + 1]), 1)
    omega = np.pi * n / max(last - first + 1, 1)
    return max(floor, FLOOR_OMEGA_TAU / omega * dt)


def lag_base(k: int, shortest: float) -> np.ndarray:
    """b_k = log τ_min + k log ρ for k = 0..K-1 (see the module notes)."""
    return np.log(shortest) + np.arange(k) * np.log(LAG_RATIO)


def lag_log_tau(theta, base):
    """The lags' log time constants (in samples) from their free parameters `theta` (K,)."""
    return base + jnp.cumsum(theta**2)


def lag_theta(log_tau, base):
    """The free parameters whose [`lag_log_tau`][] is `log_tau` (K,, increasing), after moving
    each time constant up to where the bounds allow (a start below τ_min, or closer than ρ to
    the one before, starts just above the bound instead, and the slower ones move up with it)."""
    # θ_k² is the gap between lag k and its bound: above b_0 for the fastest, above ρ times the
    # previous lag for the others. Moved onto the bounds, log τ_k - b_k is non-negative and
    # non-decreasing (a running maximum). A start on a bound gets a small gap (θ ≈ 0.03), as
    # θ = 0 would give its time constant no gradient to leave the bound by.
    q = lax.cummax(jnp.maximum(log_tau - base, 0.0))
    g = jnp.maximum(jnp.diff(q, prepend=jnp.zeros(1, q.dtype)), 1e-3)
    return jnp.sqrt(g)


def initial_time_constants(
    n_lags: int, dt: float, duration: float, shortest: float | None = None, n_starts: int | None = None
):
    """Starting time constants for `n_lags` creep lags, log-spaced across the record.

    The range runs from `shortest` (default 10 samples; the fit uses
    [`shortest_time_constant`][]) to the record's duration (slower lags look like an offset); the
    lags sit at the centres of `n_lags` equal bins of log τ over it. With `n_starts`, start i
    puts them at the fraction (1/2 + i/n_starts) mod 1 of their bins instead, so that the starts
    together cover the range evenly: the fit's error has local minima in τ, and starts that only
    scatter around the centres miss those far from them.

    **Arguments:** `n_lags`; `dt`, the sampling interval; `duration`, the fitted stretch's length;
    `shortest`, the fastest time constant allowed, in the units of `dt`; `n_starts`, None or a
    positive number of starts.

    **Returns:** (n_lags,) time constants in the units of `dt`, or (n_starts, n_lags) with
    `n_starts`; the first start's are the centres.
    """
    lo = MIN_SAMPLES * dt if shortest is None else float(shortest)
    hi = max(duration, 10.0 * lo)
    where = np.asarray([0.5]) if n_starts is None else (0.5 + np.arange(n_starts) / n_starts) % 1.0
    tau = lo * (hi / lo) ** ((np.arange(n_lags)[None, :] + where[:, None]) / max(n_lags, 1))
    return tau[0] if n_starts is None else tau
