"""Batch experiments: the one-`vmap` batch against a per-setting loop, and the noise study."""

import jax
import numpy as np
import pytest

import piest_jax as pj
from piest_jax._estimation.batch import ESTIMATORS, noise_figure, noise_study, run_batch

R = (0.0, 10 / 3, 20 / 3)
DT = 1e-3
T = 1001  # the shape of the other estimator tests, so their compiled scans are reused
t = np.arange(T) * DT
INPUTS = np.stack(
    [
        10 * np.sin(2 * np.pi * 5 * t),
        10 * np.sin(10 * np.pi * t) + 5 * np.sin(2 * np.pi * t),
        8 * np.sin(2 * np.pi * 7 * t),
        10 * np.sin(2 * np.pi * 5 * t),
    ]
)
JUMP = np.where((np.arange(T) < 500)[:, None], [2.0, 6.0, 8.0], [2.5, 5.0, 8.5])
WEIGHTS = np.stack([np.tile(w, (T, 1)) for w in ([1, 3, 5], [0, 0, 0], [1, 1, 1], [0.5, 2, 3])])
WEIGHTS[1] = JUMP
SETTINGS = dict(
    estimator=["continuous", "forgetting", "gradient", "continuous"],
    P0=[1e8, 1e3, 1.0, 1e5],
    noise_std=[0.0, 0.05, 0.02, 0.1],
    forgetting=[1.0, 0.98, 1.0, 1.0],
    gain=[1.0, 1.0, 1.5, 1.0],
)


def _settle_reference(w, truth, rtol):
    last = T
    for k in range(T - 1, -1, -1):
        if np.all(np.abs(w[k] - truth) <= rtol * np.abs(truth)):
            last = k
        else:
            break
    return last


def test_batch_equals_per_setting_loop():
    key = jax.random.PRNGKey(7)
    stats = run_batch(INPUTS, WEIGHTS, R, key=key, **SETTINGS)
    keys = jax.random.split(key, len(INPUTS))
    s = SETTINGS
    for i in range(len(INPUTS)):
        est = {
            "continuous": pj.ContinuousRLS(s["P0"][i], DT),
            "forgetting": pj.ForgettingRLS(s["P0"][i], s["forgetting"][i]),
            "gradient": pj.NormalisedGradient(s["gain"][i]),
        }[s["estimator"][i]]
        H = np.asarray(pj.play(INPUTS[i], R))
        noise = s["noise_std"][i] * np.asarray(jax.random.normal(keys[i], (T,)))
        y = np.sum(H * WEIGHTS[i], axis=1) + noise
        res = pj.estimate(est, H, y)
        w = np.asarray(res.weights)
        np.testing.assert_allclose(stats.final_weights[i], w[-1], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(stats.final_error[i], w[-1] - WEIGHTS[i, -1], atol=1e-12)
        assert int(stats.settle_index[i]) == _settle_reference(w, WEIGHTS[i, -1], 0.01)
        rms = np.sqrt(np.mean(np.asarray(res.error)[T // 2 :] ** 2))
        # e = y − hᵀŴ is a difference of O(|y|) numbers: compare on the scale of y
        atol = 1e-12 * np.abs(y).max()
        np.testing.assert_allclose(stats.rms_prediction_error[i], rms, rtol=1e-12, atol=atol)
        assert bool(stats.finite[i])
    # the noise-free RLS member settles; the jumping member needs the forgetting factor
    assert int(stats.settle_index[0]) < T


def test_noise_study_spread_bias_and_forgetting_tradeoff():
    rep = noise_study(
        key=jax.random.PRNGKey(3),
        replicates=128,
        noise_levels=(0.05,),
        forgetting=(0.9, 0.98, 1.0),
        duration=1.0,
    )
    assert rep["all_finite"]
    nz = rep["noise"]
    std, pred, bias = (np.asarray(nz[k])[0] for k in ("std", "std_predicted", "bias"))
    # Monte Carlo spread against the closed-form covariance (128 draws: about 6 % sampling error)
    np.testing.assert_allclose(std, pred, rtol=0.2)
    # no detectable bias: the mean error is within 4 standard errors of zero
    assert np.all(np.abs(bias) <= 4 * pred / np.sqrt(128))
    fg = rep["forgetting"]
    track = np.asarray(fg["time_to_1pct_after_jump"], float)
    spread = np.linalg.norm(np.asarray(fg["std"]), axis=1)
    old = np.linalg.norm(np.asarray(fg["bias"]), axis=1)
    # shorter memory re-converges sooner but averages the noise over fewer samples
    assert track[0] < track[1] < 0.5 and np.isinf(track[2])
    assert spread[0] > spread[1] > spread[2]
    # λ = 1 never forgets the old weights: its final estimate stays biased towards them
    assert old[2] > 10 * max(old[0], old[1])
    fig = noise_figure(rep)
    assert len(fig.axes) == 3
    import matplotlib.pyplot as plt

    plt.close(fig)


def test_errors():
    key = jax.random.PRNGKey(0)
    with pytest.raises(ValueError, match="unknown estimator 'lms'"):
        run_batch(INPUTS, WEIGHTS, R, key=key, estimator="lms")
    with pytest.raises(ValueError, match="`estimator` has 2 entries but the batch has 4"):
        run_batch(INPUTS, WEIGHTS, R, key=key, estimator=list(ESTIMATORS[:2]))
    with pytest.raises(ValueError, match="3 true weights per member but 2 thresholds"):
        run_batch(INPUTS, WEIGHTS, R[:2], key=key)
    with pytest.raises(ValueError, match=r"`true_weights` must be \(B, n\) or \(B, T, n\)"):
        run_batch(INPUTS, WEIGHTS[:2], R, key=key)
    with pytest.raises(ValueError, match=r"`inputs` must be \(B, T\)"):
        run_batch(INPUTS[0], WEIGHTS, R, key=key)
    with pytest.raises(ValueError, match=r"`P0` must be a scalar or have one entry per member"):
        run_batch(INPUTS, WEIGHTS, R, key=key, P0=[1.0, 2.0])
    with pytest.raises(ValueError, match="`noise_std` must be non-negative"):
        run_batch(INPUTS, WEIGHTS, R, key=key, noise_std=-1.0)
    with pytest.raises(ValueError, match=r"forgetting factor must be in \(0, 1\]"):
        run_batch(INPUTS, WEIGHTS, R, key=key, estimator="forgetting", forgetting=1.2)
    with pytest.raises(ValueError, match=r"gain must be in \(0, 2\)"):
        run_batch(INPUTS, WEIGHTS, R, key=key, estimator="gradient", gain=2.5)
    with pytest.raises(ValueError, match="`P0` must be positive definite"):
        run_batch(INPUTS, WEIGHTS, R, key=key, P0=0.0)
    with pytest.raises(ValueError, match="`inputs` contains NaN or inf"):
        run_batch(np.where(INPUTS > 9.9, np.nan, INPUTS), WEIGHTS, R, key=key)
    with pytest.raises(ValueError, match="strictly increasing"):
        run_batch(INPUTS, WEIGHTS, (0.0, 5.0, 2.0), key=key)
    with pytest.raises(ValueError, match="`replicates` must be a whole number >= 2"):
        noise_study(key=key, replicates=1)


def test_batch_convergence_study_follows_assumption1(tmp_path):
    import importlib.util
    import json
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "experiments" / "batch_convergence.py"
    spec = importlib.util.spec_from_file_location("batch_convergence", path)
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    assert script.main(["--replicates", "1", "--out", str(tmp_path)]) == 0
    assert (tmp_path / "batch_convergence.png").stat().st_size > 10_000
    rep = json.loads((tmp_path / "batch_convergence.json").read_text())
    assert rep["all_finite"] and rep["members"] == 14 * 4 * 2
    rho = np.asarray(rep["assumption1_ratio"]["1 s"])
    c1 = np.asarray(rep["pe_level_c1"]["1 s"])
    settled = np.asarray(rep["fraction_settled_1pct"])  # (input, estimator, noise)
    err = np.asarray(rep["median_final_rel_error"])
    pe = rho >= 1
    assert 0 < pe.sum() < len(pe)  # the study spans both sides of Assumption 1
    # Assumption 1 (for T0 = 1 s) and Definition 1 agree on every input of the study
    np.testing.assert_array_equal(c1 > 1e-9, pe)
    # with PE the noise-free least-squares estimators (P0 = 1e8, forgetting) converge ...
    assert np.all(settled[pe][:, 1:3, 0] == 1.0)
    # ... and without it no estimator does: ω3 is never seen, the error stays large
    assert np.all(settled[~pe] == 0.0) and np.all(err[~pe] > 0.1)


def _assert_same_stats(a, b):
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)):
        np.testing.assert_allclose(np.asarray(x), np.asarray(y), rtol=1e-12, atol=1e-12)


def test_estimator_objects_give_the_named_results():
    key = jax.random.PRNGKey(3)
    sigma = [0.0, 0.05, 0.02, 0.1]
    named = run_batch(
        INPUTS,
        WEIGHTS,
        R,
        key=key,
        estimator="forgetting",
        P0=1e3,
        forgetting=[1.0, 0.98, 0.99, 0.995],
        noise_std=sigma,
    )
    # One object per member: the array settings are stacked and batched.
    objects = [pj.ForgettingRLS(1e3, lam) for lam in (1.0, 0.98, 0.99, 0.995)]
    _assert_same_stats(run_batch(INPUTS, WEIGHTS, R, key=key, estimator=objects, noise_std=sigma), named)
    # One object shared by every member.
    shared = run_batch(INPUTS, WEIGHTS, R, key=key, estimator=pj.ContinuousRLS(1e8, DT), noise_std=sigma)
    _assert_same_stats(
        shared, run_batch(INPUTS, WEIGHTS, R, key=key, estimator="continuous", P0=1e8, dt=DT, noise_std=sigma)
    )


def test_estimator_objects_are_checked():
    key = jax.random.PRNGKey(0)
    with pytest.raises(ValueError, match="the class ContinuousRLS, not an estimator"):
        run_batch(INPUTS, WEIGHTS, R, key=key, estimator=pj.ContinuousRLS)
    with pytest.raises(ValueError, match="one batch runs one estimator class"):
        run_batch(
            INPUTS, WEIGHTS, R, key=key, estimator=[pj.ContinuousRLS(1.0, DT)] * 2 + [pj.NormalisedGradient(1.0)] * 2
        )
    with pytest.raises(ValueError, match="`P0` is a setting of the estimator object"):
        run_batch(INPUTS, WEIGHTS, R, key=key, estimator=pj.ContinuousRLS(1.0, DT), P0=5.0)
    with pytest.raises(ValueError, match="static settings"):
        run_batch(
            INPUTS,
            WEIGHTS,
            R,
            key=key,
            estimator=[pj.ContinuousRLS(1.0, DT)] * 3 + [pj.ContinuousRLS(1.0, DT, normalisation="standard")],
        )
    with pytest.raises(ValueError, match="set up for 2 plays but there are 3 thresholds"):
        run_batch(INPUTS, WEIGHTS, R, key=key, estimator=pj.ContinuousRLS(np.eye(2), DT))
