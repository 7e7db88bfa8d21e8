"""The map's verdicts that floating point cannot decide, decided in exact arithmetic.

The exact condition's float level (the event matrix's λ_min / λ_max) is known only to its
rounding error, and a draw's raw Gram level only to a few eps times its largest eigenvalue. A
draw whose event level is below `settle_band`, or whose two float verdicts disagree, has its
play outputs' rank taken in exact arithmetic (`exact_draw_pe`), from the very input floats the
map judged (the map hands them over chunk by chunk). In exact arithmetic the event matrix's
rank is the play outputs' rank (the row operations of Theorem 2 in
`docs/excitation_condition.md`), so that one rank settles both verdicts; above the band the
float level decides.
"""

import functools

import jax
import jax.numpy as jnp
import numpy as np

from .._operators.play import _bank
from .exact_arithmetic import exact_draw_pe
from .exact_condition import _event_level
from .map_result import PEMap
from .map_settings import MapSettings, numerical_tolerance


def settle_band(n_samples: int, n_plays: int, dtype) -> float:
    """The event level below which a draw's exact-condition verdict is settled exactly.

    The event Gram of a window is a difference of two running sums over at most T rows of
    entries in [0, 1]; each sum is off by at most T² eps per entry, so the matrix by at most
    2 n T² eps in norm, and its eigenvalues alike (Weyl). Its largest eigenvalue is at least 1
    (the window's first row is scaled to max |h_a| = 1, and a moving play contributes a 1), so
    the level λ_min / λ_max is off by at most about 2 n T² eps: 1.1e-7 for T = 5000 and ten
    plays in float64. Below that (or below `numerical_tolerance`, whichever is larger) the
    float verdict can be wrong either way.

    **Arguments:** `n_samples` T, `n_plays` n, `dtype` of the map.

    **Returns:** the band's upper edge, a Python float.
    """
    eps = float(jnp.finfo(jnp.dtype(dtype)).eps)
    return max(2.0 * n_plays * n_samples**2 * eps, numerical_tolerance(dtype))


def needs_settling(result: PEMap) -> np.ndarray:
    """Which draws of a map float arithmetic cannot decide: event level below the band, or the
    raw Gram and the exact condition disagreeing.

    **Arguments:** `result`, a [`PEMap`][] from [`pe_map`][].

    **Returns:** (n_draws,) booleans, True where the draw needs settling.
    """
    return _undecided(result.c1_normalised, result.exact_level, result.exact, result.settings)


def _undecided(c1_normalised, exact_level, exact, settings: MapSettings) -> np.ndarray:
    s = settings
    raw_pe = np.asarray(c1_normalised) > numerical_tolerance(s.dtype)
    low = np.asarray(exact_level) < settle_band(s.n_samples, s.n_plays, s.dtype)
    return low | (raw_pe != np.asarray(exact))


@functools.lru_cache(maxsize=8)
def _levels(settings: MapSettings):
    s = settings

    @jax.jit
    def fn(u, r, x0):
        return _event_level(_bank(u, r, x0, s.play_method), u, r, s.window, s.stride)

    return fn


def settle_draws(stats: dict, settings: MapSettings) -> dict:
    """Decide in exact arithmetic every draw of a chunk of the map that `needs_settling`.

    **Arguments:** `stats`, the map's per-draw statistics for a chunk, with the drawn inputs
    `u` (draws, T), `x0` and `thresholds` (draws, n): the very floats the map judged; `settings`
    of the map.

    **Returns:** `stats` without `u` and `x0`, with `pe` (the PE verdict: exact where settled,
    else the raw Gram level above `numerical_tolerance`), `exact` (the exact condition: exact
    where settled and the event level is below the band, else the float verdict) and `settled`
    (which draws were decided exactly).
    """
    s = settings
    band = settle_band(s.n_samples, s.n_plays, s.dtype)
    out = dict(stats)
    u, x0, r = out.pop("u"), out.pop("x0"), stats["thresholds"]
    pe = np.asarray(stats["c1_normalised"]) > numerical_tolerance(s.dtype)
    exact = np.array(stats["exact"], dtype=bool)
    settled = _undecided(stats["c1_normalised"], stats["exact_level"], stats["exact"], s)
    for i in np.flatnonzero(settled):
        # The windows with the lowest float levels first: a deficient draw stops at its first.
        order = np.argsort(np.asarray(_levels(s)(u[i], r[i], x0[i])))
        truth = exact_draw_pe(u[i], r[i], x0[i], s.window, stride=s.stride, order=order)
        pe[i] = truth
        if stats["exact_level"][i] < band:
            exact[i] = truth
    return out | dict(pe=pe, exact=exact, settled=settled)
