"""Isolated spikes in a measured output: one sample far from both neighbours, which agree.

A sensor glitch (a dropped bit, a spike on the line) moves one sample by much more than the
signal moves from one sample to the next, and the next sample returns to where the one before
was. Hysteresis, creep and noise do not do that: a real step stays, and noise is on the scale
of the typical increment.
"""

import numpy as np

# A spike's two increments exceed this many robust standard deviations of the record's increments,
# and this share of the output's robust range.
SPIKE_SIGMAS = 20.0
SPIKE_RANGE = 0.01


def isolated_spikes(y) -> np.ndarray:
    """The samples of `y` (T,) that are isolated spikes, as sorted indices.

    Sample i (not the first or last) is one when its increments from the sample before and to
    the sample after have opposite signs, both exceed `SPIKE_SIGMAS` times the robust standard
    deviation of the second differences (1.4826 × their median absolute deviation) and
    `SPIKE_RANGE` of the output's range between its 1st and 99th percentiles, the two
    neighbours differ by less than half the smaller increment, and the increments into and out
    of the neighbours stay below a quarter of it (ringing after a step moves them too).
    """
    y = np.asarray(y, np.float64)
    if y.size < 3:
        return np.zeros(0, int)
    d = np.diff(y)
    # The scale of how increments change from sample to sample (second differences): noise, and
    # a smooth signal's curvature, but not its slope.
    d2 = np.diff(d)
    moving = d2[d2 != 0]
    if moving.size == 0:
        return np.zeros(0, int)
    sigma = 1.4826 * float(np.median(np.abs(moving - np.median(moving))))
    lo, hi = np.percentile(y, [1, 99])
    floor = max(SPIKE_SIGMAS * sigma, SPIKE_RANGE * float(hi - lo), np.finfo(float).tiny)
    before, after = d[:-1], d[1:]
    small = np.minimum(np.abs(before), np.abs(after))
    back = np.abs(y[2:] - y[:-2])
    # The increments into the neighbours and out of them: calm beside a spike, not in ringing.
    pad = np.concatenate([[0.0], d, [0.0]])
    calm = np.maximum(np.abs(pad[:-3]), np.abs(pad[3:])) < 0.25 * small
    hit = (np.sign(before) == -np.sign(after)) & (small > floor) & (back < 0.5 * small) & calm
    return np.flatnonzero(hit) + 1


def without_spikes(y, rows) -> np.ndarray:
    """`y` with the samples `rows` replaced by the mean of their two neighbours."""
    y = np.array(y, np.float64)
    rows = np.asarray(rows, int)
    y[rows] = 0.5 * (y[rows - 1] + y[rows + 1])
    return y
