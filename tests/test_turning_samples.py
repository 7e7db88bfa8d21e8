"""Sub-sampling that keeps the plays exact: the turning samples between kept samples.

The diagnosis searches long records on every k-th sample; its plays run on those samples plus the
suffix extrema between them (`turning_samples`), which must give the full-rate plays at the kept
samples exactly, whatever the input, thresholds, initial states and step.
"""

import numpy as np
import reference as ref
from hypothesis import given, settings
from hypothesis import strategies as st

from piest_jax._data.record import Record
from piest_jax._diagnosis import basis as _basis
from piest_jax._diagnosis.scaling import prepared, scaling_of


@settings(max_examples=200, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    n=st.integers(2, 300),
    step=st.integers(1, 40),
    levels=st.sampled_from([0, 3, 7]),
)
def test_plays_on_turning_samples_equal_the_full_rate_plays(seed, n, step, levels):
    rng = np.random.default_rng(seed)
    # Random walks, optionally quantised so that equal values (ties) are common.
    u = np.cumsum(rng.normal(size=n))
    if levels:
        u = np.round(u * levels / max(np.ptp(u), 1e-9))
    r = np.sort(rng.uniform(0, 0.6 * max(np.ptp(u), 1.0), 5))
    r[0] = 0.0
    x0 = u[0] + rng.uniform(-1, 1, 5) * r
    index, keep = _basis.turning_samples(u, step)
    assert np.all(np.diff(index) > 0) and index[0] == 0
    full = ref.play(u, r, x0)
    kept = np.arange(0, ((n - 1) // step) * step + 1, step)
    assert np.array_equal(index[keep], kept)
    reduced = ref.play(u[index], r, x0)[keep]
    assert np.array_equal(reduced, full[kept])
    assert np.array_equal(_basis.plays(u[index], r, x0[None], keep)[0], full[kept])


def test_a_subsampled_record_keeps_its_peaks():
    # A 2 Hz sine at 10 kHz searched on every 500th sample: the kept samples miss the peaks,
    # the plays on the turning samples do not.
    t = np.arange(200_001) * 1e-4
    u = np.sin(2 * np.pi * 2.0 * t + 0.3)
    rng = np.random.default_rng(0)
    rec = Record(t, u + 1e-3 * rng.normal(size=t.size), u.copy())
    sc = scaling_of(rec)
    p = prepared(rec, sc, step=500)
    full = prepared(rec, sc)
    want = _basis.plays(full.u, _basis.THRESHOLDS, np.full((1, _basis.N_PLAYS), full.u[0]))[0][::500]
    assert np.allclose(p.plain_plays(), want, rtol=0, atol=1e-12)
    naive = _basis.plays(p.u, _basis.THRESHOLDS, np.full((1, _basis.N_PLAYS), p.u[0]))[0]
    assert np.max(np.abs(naive - want)) > 1e-3
    # Bounded work: a few suffix extrema per stretch, not the full rate.
    assert len(p.play_u) < 20 * len(p.u)
