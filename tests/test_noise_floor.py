"""The diagnosis's noise floor under coloured noise: the local cubic's floor at a coarser step and
the effective sample size, against closed forms for AR(1) noise; the input's half cycle;
and a record with AR(1) sensor noise named exactly."""

import jax
import numpy as np
import pytest

from piest_jax._diagnosis import diagnose as _diagnose
from piest_jax._diagnosis import hidden as _hidden
from piest_jax._diagnosis import scaling as _scaling


def _ar1(phi, sigma, n, seed):
    """AR(1) noise of lag-one correlation phi and std sigma, stationary from the first sample."""
    w = np.random.default_rng(seed).normal(0, sigma, n)
    e = np.empty(n)
    e[0] = w[0]
    for i in range(1, n):
        e[i] = phi * e[i - 1] + np.sqrt(1 - phi**2) * w[i]
    return e


def _cubic_residual_row(width=7):
    """The residual of a centred least-squares cubic over `width` samples, as weights on them."""
    x = np.arange(width) - width // 2
    V = np.vander(x, 4, increasing=True)
    hat = V @ np.linalg.solve(V.T @ V, V.T)
    return np.eye(width)[width // 2] - hat[width // 2]


def _floor_closed_form(phi, sigma, step):
    """What the 7-sample floor reads on AR(1) noise run on every `step`-th sample.

    The decimated noise is AR(1) with phi^step; the residual a . e has variance
    sigma^2 sum_jk a_j a_k phi^(step |j - k|), and the floor divides by the white-noise value
    sum_k a_k^2 (= 1 - h0), so white noise reads sigma.
    """
    a = _cubic_residual_row()
    lag = np.abs(np.subtract.outer(np.arange(7), np.arange(7)))
    return sigma * np.sqrt(a @ (phi ** (step * lag)) @ a / (a @ a))


@pytest.mark.parametrize("phi", [0.0, 0.5, 0.8])
def test_noise_floor_of_ar1_noise_matches_the_closed_form(phi):
    e = _ar1(phi, 0.3, 100_000, seed=1)
    for step in (1, 3, 40):
        assert _scaling.noise_std(e, step) == pytest.approx(_floor_closed_form(phi, 0.3, step), rel=0.02)
    # A step well beyond the correlation time reads the whole variance; the 7-sample floor
    # reads a small part of it once the noise is coloured.
    assert _scaling.noise_std(e, 40) == pytest.approx(0.3, rel=0.02)
    if phi == 0.8:
        assert _scaling.noise_std(e) < 0.5 * 0.3


def test_noise_floor_step_is_checked():
    with pytest.raises(ValueError, match="`step` must be in \\[1, 2\\] for 20 samples, got 3"):
        _scaling.noise_std(np.zeros(20), 3)
    with pytest.raises(ValueError, match="got 0"):
        _scaling.noise_std(np.zeros(20), 0)


@pytest.mark.parametrize("phi", [0.0, 0.5, 0.8])
def test_effective_samples_of_ar1_noise(phi):
    n = 200_000
    e = _ar1(phi, 1.0, n, seed=2)
    # The integrated autocorrelation time of AR(1) is (1 + phi) / (1 - phi).
    assert _scaling.effective_samples(e, 100) == pytest.approx(n * (1 - phi) / (1 + phi), rel=0.05)
    # Only lags up to max_lag are counted: one lag gives n / (1 + 2 phi).
    assert _scaling.effective_samples(e, 1) == pytest.approx(n / (1 + 2 * phi), rel=0.02)
    assert _scaling.effective_samples(np.zeros(10), 5) == 10


def test_half_cycle_is_the_median_reversal_spacing():
    k = np.arange(2000)
    assert _scaling.half_cycle(np.sin(2 * np.pi * k / 100)) == 50
    # The median: 17 spacings of 100 samples outweigh 10 of 20.
    u = np.where(k < 1800, np.sin(2 * np.pi * k / 200), np.sin(2 * np.pi * k / 40))
    assert _scaling.half_cycle(u) == 100
    u[1000:] = np.where(k[1000:] < 1800, np.sin(2 * np.pi * k[1000:] / 40), u[1000:])
    assert _scaling.half_cycle(u) == 20
    assert _scaling.half_cycle(k.astype(float)) == 2000


@pytest.mark.parametrize("effect, seed", [("delay", 2), ("linear_dynamics", 0)])
def test_single_effect_under_ar1_noise_is_named_exactly(effect, seed):
    # AR(1) sensor noise (phi = 0.9) reads about 0.3x its std on the 7-sample floor; judged
    # against that, both records also got `offset_drift`, a fit to the slow noise.
    rec, truth = _hidden.generate((effect,), key=jax.random.PRNGKey(seed), n_samples=1200, noise_ar=0.9)
    s = _diagnose.search(rec, solver=None, uncertainty=False)
    assert s["effects"] == [effect]
    seven = _scaling.noise_std(rec.y)
    assert seven < 0.35 * truth["noise_std"]
    assert 1.5 * seven < s["noise_std"] < 1.1 * truth["noise_std"]


def test_a_round_takes_the_smaller_floor_and_the_larger_sample_count(monkeypatch):
    # The plain model's residual holds the drift's slow misfit, which correlates it: it counts
    # far fewer effective samples than the drift model's residual, whose count judges the round.
    rec, _ = _hidden.generate(("offset_drift",), key=jax.random.PRNGKey(4), n_samples=2000, noise_ar=0.8)
    s = _diagnose.search(rec, solver=None, uncertainty=False, candidates=("offset_drift",), max_effects=1)
    assert s["effects"] == ["offset_drift"]
    # Short enough that the search ran on every sample, as the record prepared here.
    assert rec.n_samples <= _diagnose.SEARCH_SAMPLES
    sc = s["scaling"]
    p = _scaling.prepared(rec, sc, folds=True)
    floor = _scaling.noise_std(rec.y) / sc.y_half
    step = _diagnose._noise_step(p)
    plain = _diagnose._noise(p, {}, floor, step)
    drift = _diagnose._noise(p, s["model_final"]["cfg"], floor, step)
    assert plain[1] < 0.25 * drift[1]
    first = s["rounds"][0]
    assert first["effective_samples"] == pytest.approx(drift[1])
    assert (first["noise_std"] / sc.y_half) ** 2 == pytest.approx(min(plain[0], drift[0]))
    # Where the smaller floor comes with the smaller count (a 10^6-sample AR(1) record with a
    # drift did this), the count still comes from the other residual.
    measured = iter([(1.0, 12.0), (2.0, 55.0)])
    monkeypatch.setattr(_diagnose, "_noise", lambda *args: next(measured))
    assert _diagnose._round_noise(p, {}, {}, floor, step) == (1.0, 55.0)
