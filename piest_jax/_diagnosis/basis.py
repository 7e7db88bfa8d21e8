"""The play basis of every diagnosis model: plays on a dense, fixed threshold grid.

In normalised units (input scaled to [-1, 1]) the grid r_j = j / N_PLAYS spans every loop the
input can open, so a PI model is a linear combination of these columns and the diagnosis fits
weights, not thresholds. This module holds the plays themselves (one pass for a batch of initial
states, thresholds that may vary over time) and the exact sub-sampling that lets a long record be
searched on a few thousand samples.
"""

import numpy as np

N_PLAYS = 16
THRESHOLDS = np.arange(N_PLAYS) / N_PLAYS


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
