"""The Preisach fit's covariance: the chunked score sums against a dense NumPy computation, the
standard errors against the spread of the estimates over noise draws, held and undetermined
cells, and fit.json."""

import json

import jax
import numpy as np
import pytest
import reference as ref

import piest_jax as pj
from piest_jax._identification import covariance as _cov
from piest_jax._identification import preisach_covariance

jax.config.update("jax_enable_x64", True)

K, M = 6, 6


def signal(T=800, seed=0):
    t = np.linspace(0.0, 1.0, T)
    phase = np.random.default_rng(seed).uniform(0, 2 * np.pi)
    return 2.0 * np.sin(2 * np.pi * 6 * t) * (0.3 + 0.7 * np.abs(np.sin(2 * np.pi * 0.9 * t + phase)))


def dense_relays(u, half_widths, centres, blur, x0):
    # Plays from the reference loop, then the blurred relays: clip((H_k - c_m)/δ_m, -1, 1).
    H = np.stack([ref.play(u, r, x) for r, x in zip(half_widths, x0)], axis=1)
    return np.clip((H[:, :, None] - centres) / blur, -1.0, 1.0).reshape(len(u), -1)


@pytest.mark.parametrize("window,chunk", [(1, 64), (7, 50), (90, 64)])
def test_score_blocks_equal_the_dense_sums(window, chunk):
    rng = np.random.default_rng(window)
    u = signal(301)
    r, c, d = np.arange(K) / K * 2.0, np.linspace(-1.6, 1.6, M), np.full(M, 0.5)
    x0 = np.full(K, u[0])
    e = rng.standard_normal(u.size)
    keep = np.array([0, 3, 8, 20, K * M])
    B = np.concatenate([dense_relays(u, r, c, d, x0), np.ones((u.size, 1))], axis=1)[:, keep]
    g = B * e[:, None]
    W = np.array([g[t - window + 1 : t + 1].sum(0) for t in range(window - 1, u.size)])
    got = preisach_covariance.score_blocks(u, e, r, c, d, x0, keep, window, chunk)
    np.testing.assert_allclose(got, W.T @ W, rtol=1e-10, atol=1e-10)


def _truth(u):
    # A smooth density over the grid fit_preisach builds (centres tiling the input range, half
    # widths up to half of it), so the model is in the fitted class.
    f = pj.fit_preisach(u, np.tanh(u) + 0.1 * u, n_widths=K, n_centres=M, smoothness=1e-3, covariance=None)
    return np.asarray(f.model(u))


@pytest.mark.parametrize("method", _cov.METHODS)
def test_calibration_over_noise_draws(method):
    # At a fixed smoothness the estimate is linear in y: over 200 white-noise draws the spread of
    # each estimate is the sandwich's, known to about 5 % from 200 draws, so the 0.8-1.25 band
    # on (mean predicted std error) / (spread) is four of its standard errors wide.
    u = signal()
    y0 = _truth(u)
    noise = 0.02 * np.random.default_rng(3).standard_normal((200, u.size))
    est, se = [], []
    for e in noise:
        f = pj.fit_preisach(u, y0 + e, n_widths=K, n_centres=M, smoothness=1e-3, covariance=method)
        est.append(np.asarray(f.parameter_values))
        se.append(np.asarray(f.std_errors))
    assert f.undetermined_names == () and f.covariance_method == method
    ratio = np.mean(se, axis=0) / np.std(est, axis=0, ddof=1)
    assert np.all((0.8 < ratio) & (ratio < 1.25)), dict(zip(f.parameter_names, ratio))
    # The smoothing spends fewer parameters than there are cells.
    assert 1 < f.effective_parameters < len(f.parameter_names)


def test_cells_held_at_zero_and_cells_the_record_never_switches():
    u = signal()
    y = _truth(u) + 0.02 * np.random.default_rng(1).standard_normal(u.size)
    f = pj.fit_preisach(u, y, n_widths=K, n_centres=M, monotone=True)
    held = np.asarray(f.parameter_values)[:-1] == 0
    assert held.any()
    se = np.asarray(f.std_errors)[:-1]
    np.testing.assert_array_equal(se[held], 0.0)
    assert np.all(np.isfinite(se[~held]) & (se[~held] > 0))
    # An input that stays in the upper part of its range after a first dip: the relays of the
    # lower part switch once at most, together, and the record cannot tell them apart.
    v = np.concatenate([np.linspace(0.0, -2.0, 50), 1.0 + np.abs(signal(750))])
    g = pj.fit_preisach(
        v,
        np.tanh(v) + 0.01 * np.random.default_rng(2).standard_normal(v.size),
        n_widths=K,
        n_centres=M,
        smoothness=1e-3,
    )
    bad = g.undetermined_names
    assert bad and all(n.startswith("density[") for n in bad)
    assert np.all(np.isinf(np.asarray(g.std_errors)[np.asarray(g.undetermined)]))


def test_no_covariance_and_a_bad_name():
    u = signal(300)
    f = pj.fit_preisach(u, np.tanh(u), n_widths=4, n_centres=4, covariance=None)
    assert f.std_errors is None and f.undetermined_names == ()
    with pytest.raises(ValueError, match="unknown covariance 'sandwich'"):
        pj.fit_preisach(u, np.tanh(u), n_widths=4, n_centres=4, covariance="sandwich")


def test_cli_fit_json_has_a_standard_error_for_every_parameter(tmp_path):
    u = signal(600)
    y = np.tanh(u) + 1e-3 * np.random.default_rng(1).standard_normal(u.size)
    data = tmp_path / "r.csv"
    data.write_text("t,u,y\n" + "\n".join(f"{i * 1e-3:.6f},{a:.17g},{b:.17g}" for i, (a, b) in enumerate(zip(u, y))))
    assert (
        pj.run_cli(["fit", str(data), "--model", "preisach", "--grid", "6,6", "--out", str(tmp_path / "o"), "--quiet"])
        == 0
    )
    rep = json.loads((tmp_path / "o" / "fit.json").read_text())
    names = rep["covariance"]["parameter_names"]
    assert names[-1] == "offset" and len(names) == 1 + sum(n.startswith("density[") for n in names)
    assert list(rep["std_errors"]) == names
    assert np.shape(rep["covariance"]["matrix"]) == (len(names), len(names))
    assert "standard errors" in (tmp_path / "o" / "fit.md").read_text()
