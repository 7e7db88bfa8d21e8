"""The play basis of every diagnosis model: plays on a dense, fixed threshold grid.

In normalised units (input scaled to [-1, 1]) the grid r_j = j / N_PLAYS spans every loop the
input can open, so a PI model is a linear combination of these columns and the diagnosis fits
weights, not thresholds. This module holds the plays themselves (the play operator, one pass for
a batch of initial states, thresholds that may vary over time) and the exact sub-sampling that
lets a long record be searched on a few thousand samples.
"""

import jax
import numpy as np

from .. import _checks
from .._identification.fit_data import pad_count
from .._operators.play import Method, _bank

N_PLAYS = 16
THRESHOLDS = np.arange(N_PLAYS) / N_PLAYS


# Sets of initial states from which time-varying thresholds take the associative form.
ASSOCIATIVE_BATCH = 8


# Jitted at module level, so that the diagnosis's many calls on one record's lengths reuse one
# compiled program per shape. "auto" is the compiled kernel for constant thresholds (one call for
# the whole batch of initial states) and, on a CPU, the scan for time-varying ones. The associative
# form's composed clamps do not depend on the initial states, so a batch shares them and only the
# last clamp is per set, while the scan's cost grows with every set: on a CPU, with 6,000 samples,
# the associative form was the faster from between 4 and 8 sets on. All forms give the same
# outputs to the last bit.
@jax.jit
def _batch(g, r, x0, keep):
    method: Method = "associative" if r.ndim == 2 and x0.shape[0] >= ASSOCIATIVE_BATCH else "auto"

    def one(x):
        # The bank without `play`'s checks of traced values: `plays` checked its NumPy inputs,
        # and a check inside would be a host callback, which keeps the program out of the
        # persistent compilation cache of `piest diagnose`.
        h = _bank(g, r, x, method, check_finite=False)
        # Read inside the program, the kept samples alone leave it (and the associative form
        # clamps at them alone).
        return h if keep is None else h[keep]

    return jax.vmap(one)(x0)


def _padded(a, n: int):
    """`a` with its last entry (row) repeated to length n."""
    return a if len(a) == n else np.concatenate([a, np.broadcast_to(a[-1], (n - len(a), *a.shape[1:]))])


def plays(g, r, x0, keep=None):
    """Play outputs for several initial states at once: the play operator, batched over states.

    The outputs are those of `piest_jax.play` in JAX's default precision (float64 when x64 is
    enabled, as the command line does; the library leaves that setting to its user), returned as
    NumPy float64 for the rest of the diagnosis. max and min only select, so in float64 they
    equal a float64 loop over the samples to the last bit.

    **Arguments:** `g` (T,), the (transformed) input; `r`, thresholds (n,) or time-varying (T, n);
    `x0` (C, n), C sets of initial states; `keep`, the sample positions to return (default all).

    **Returns:** (C, T, n), or (C, len(keep), n), as a NumPy float64 array.
    """
    g = np.asarray(g, float)
    x0 = np.asarray(x0, float)
    r = np.asarray(r, float)
    for a, name in ((g, "g"), (x0, "x0"), (r, "r")):
        _checks.finite(a, name)
    if np.any(r < 0):
        raise ValueError(f"`r` must be non-negative, got min {r.min():.6g}")
    if r.ndim < 2:
        r = np.broadcast_to(r, x0.shape[-1:])
    T = len(g)
    # Nearby lengths share one compiled program. The padding comes after the last sample, so no
    # output kept depends on it; repeating the last sample keeps it valid input.
    g = _padded(g, T + pad_count(T))
    if r.ndim == 2:
        r = _padded(r, len(g))
    if keep is not None:
        keep = np.asarray(keep, np.intp)
        n_keep = len(keep)
        keep = _padded(keep, n_keep + pad_count(n_keep))
    out = np.asarray(_batch(g, r, x0, keep), dtype=np.float64)
    return out[:, :T].copy() if keep is None else out[:, :n_keep].copy()


def history_states(u0, turns):
    """Play states left by an input history u0 -> turns[0] -> turns[1] ... -> u0, from rest at u0.

    **Arguments:** `u0`, the first input sample; `turns`, the turning points (normalised units).

    **Returns:** the states (n,) on the threshold grid.
    """
    x = np.full(N_PLAYS, float(u0))
    for a in [*turns, u0]:
        x = np.clip(x, a - THRESHOLDS, a + THRESHOLDS)
    return x


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
    edge = np.ones((n_seg, 1))
    after_max = np.concatenate([-np.inf * edge, np.maximum.accumulate(rev, axis=1)[:, :-1]], axis=1)[:, ::-1]
    after_min = np.concatenate([np.inf * edge, np.minimum.accumulate(rev, axis=1)[:, :-1]], axis=1)[:, ::-1]
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
