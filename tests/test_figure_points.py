"""Long records are drawn from fewer points that look the same (`figures.bin_extremes`, ...)."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

import piest_jax as pj
from piest_jax._identification import figures


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 5000), st.integers(2, 300), st.integers(0, 2**31 - 1))
def test_bin_extremes_keep_every_bins_extremes(T, bins, seed):
    rng = np.random.default_rng(seed)
    t = np.arange(T) * 0.1
    lower = np.cumsum(rng.standard_normal(T))
    upper = lower + rng.random(T)
    tb, lo, hi = figures.bin_extremes(t, lower, upper, bins)
    if T <= 2 * bins:
        assert tb is t or np.array_equal(tb, t)
        np.testing.assert_array_equal(lo, lower)
        np.testing.assert_array_equal(hi, upper)
        return
    k = -(-T // bins)
    assert tb.size <= bins and np.all(np.diff(tb) > 0)
    np.testing.assert_array_equal(tb, t[::k])
    np.testing.assert_array_equal(lo, [lower[i : i + k].min() for i in range(0, T, k)])
    np.testing.assert_array_equal(hi, [upper[i : i + k].max() for i in range(0, T, k)])


def test_loop_stretches_are_spread_over_the_record():
    idx, gaps = figures.loop_stretches(10**7, max_points=10_000, stretches=20)
    assert idx.size == 10_000 and gaps.sum() == 20 and idx[0] == 0 and idx[-1] == 10**7 - 1
    starts = idx[np.r_[True, gaps[:-1]]]
    assert np.all(np.diff(starts) > 500)  # apart: no stretch overlaps the next
    assert np.all(np.diff(idx)[~gaps[:-1]] == 1)  # each stretch is consecutive samples
    short, none = figures.loop_stretches(500)
    np.testing.assert_array_equal(short, np.arange(500))
    assert not none.any()


def test_a_long_record_figure_draws_few_points():
    T = 3 * figures.MAX_POINTS
    t = np.arange(T) * 1e-3
    u = np.sin(2 * np.pi * t)
    e = 0.01 * np.cos(7 * t)
    rec = pj.Record(t, u, u + e)
    fig = pj.fit_figure(rec, u, band=(u - 0.05, u + 0.05))
    for ax in fig.axes:
        for line in ax.get_lines():
            assert line.get_xdata().size <= figures.MAX_POINTS + figures.STRETCHES
        for c in ax.collections:
            assert sum(len(p.vertices) for p in c.get_paths()) <= 2 * figures.BINS + 10
    # The title's RMSE uses every sample, and the legend says what the loop shows.
    assert f"RMSE {np.sqrt(np.mean(e**2)):.4g}" in fig.axes[1].get_title()
    texts = [x.get_text() for x in fig.axes[0].get_legend().get_texts()]
    assert f"measured ({figures.STRETCHES} stretches of {figures.MAX_POINTS // figures.STRETCHES})" in texts
    short = pj.fit_figure(pj.Record(t[:1000], u[:1000], u[:1000] + e[:1000]), u[:1000])
    assert [x.get_text() for x in short.axes[0].get_legend().get_texts()] == ["measured", "model"]
    assert short.axes[1].get_lines()[0].get_xdata().size == 1000


def test_a_transient_does_not_set_the_residual_axis():
    from piest_jax._identification.figures import residual_limits

    rng = np.random.default_rng(0)
    e = 0.1 * rng.standard_normal(5000)
    lo, hi, clipped = residual_limits(e)
    assert not clipped and lo < e.min() and hi > e.max() and hi - lo < 1.3 * np.ptp(e)
    e[:10] = -25.0 + np.arange(10)  # a start-up transient, 100x the rest
    lo, hi, clipped = residual_limits(e)
    assert clipped and lo > -1.0 and hi < 1.0
    assert np.mean((e >= lo) & (e <= hi)) > 0.99
