"""Long records are drawn from fewer points that look the same (`figures.envelope`, ...)."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

import piest_jax as pj
from piest_jax._identification import figures


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 5000), st.integers(2, 300), st.integers(0, 2**31 - 1))
def test_envelope_keeps_every_bins_extremes(T, bins, seed):
    rng = np.random.default_rng(seed)
    t = np.arange(T) * 0.1
    y = np.cumsum(rng.standard_normal(T))
    te, ye = figures.envelope(t, y, bins)
    assert te.size <= max(T, 2 * bins + T // max(1, -(-T // bins)))
    assert np.all(np.diff(te) >= 0)
    # Every point drawn is a sample, and each bin of consecutive samples keeps its extremes.
    np.testing.assert_array_equal(ye, y[np.searchsorted(t, te)])
    if T > 2 * bins:
        k = -(-T // bins)
        for start in range(0, T // k * k, k):
            inside = (te >= t[start]) & (te <= t[start + k - 1])
            assert ye[inside].min() == y[start:start + k].min() and ye[inside].max() == y[start:start + k].max()
    else:
        np.testing.assert_array_equal(ye, y)


def test_band_envelope_covers_the_band():
    rng = np.random.default_rng(1)
    T = 100_003
    t = np.arange(T) * 1e-3
    lower = rng.standard_normal(T) - 1
    upper = lower + 2 + rng.random(T)
    tb, lo, hi = figures.band_envelope(t, lower, upper, bins=1000)
    assert tb.size <= 1001 and np.all(np.diff(tb) > 0)
    # Each drawn edge is the most extreme edge of its bin of samples.
    k = -(-T // 1000)
    np.testing.assert_array_equal(lo, [lower[i:i + k].min() for i in range(0, T, k)])
    np.testing.assert_array_equal(hi, [upper[i:i + k].max() for i in range(0, T, k)])


def test_loop_points_keep_the_reversals():
    t = np.linspace(0, 40, 400_001)
    u = np.sin(2 * np.pi * 0.7 * t) * (1 + 0.2 * np.sin(t))
    idx = figures.loop_points(u, max_points=10_000)
    du = np.diff(u)
    turns = np.flatnonzero(du[1:] * du[:-1] < 0) + 1
    assert np.isin(turns, idx).all() and idx[0] == 0 and idx[-1] == u.size - 1
    assert idx.size <= 10_000 + turns.size + 1
    np.testing.assert_array_equal(figures.loop_points(u[:500]), np.arange(500))


def test_a_long_record_figure_draws_few_points():
    T = 3 * figures.MAX_POINTS
    t = np.arange(T) * 1e-3
    u = np.sin(2 * np.pi * t)
    rec = pj.Record(t, u, u + 0.01 * np.cos(7 * t))
    fig = pj.fit_figure(rec, u, band=(u - 0.05, u + 0.05))
    reversals = 2 * 3 * figures.MAX_POINTS // 1000  # two per cycle of the 1 Hz sine
    for ax in fig.axes:
        for line in ax.get_lines():
            assert line.get_xdata().size <= figures.MAX_POINTS + reversals + 1 < T / 2
    # The title's RMSE uses every sample.
    assert f"RMSE {np.sqrt(np.mean((0.01 * np.cos(7 * t)) ** 2)):.4g}" in fig.axes[1].get_title()
