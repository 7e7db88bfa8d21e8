"""Online estimation on a record, streamed in chunks (`estimate_record`, `piest estimate`).

The chunked run must equal one scan over the whole record (the plays' and the estimator's states
carried across chunks), and everything it reports is checked against an independent computation.
"""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import reference as ref

import piest_jax as pj
from piest_jax import estimate_record, settled_start
from piest_jax._cli import main

R = np.array([0.0, 0.4, 0.9, 1.5])
W = np.array([1.0, 0.6, 0.4, 0.3])
DT = 0.01


def _record(n=900, seed=0, noise=0.0):
    rng = np.random.default_rng(seed)
    t = np.arange(n) * DT
    u = 2.0 * np.sin(2 * np.pi * 0.7 * t) + 0.7 * np.sin(2 * np.pi * 1.9 * t + 0.4)
    y = np.asarray(pj.PIOperator(jnp.asarray(R), jnp.asarray(W), jnp.full(4, u[0]))(jnp.asarray(u)))
    return u, y + 0.5 + noise * rng.normal(size=n)


@pytest.mark.parametrize("chunk", [64, 100, 4096])
def test_chunks_equal_one_scan_over_the_record(chunk):
    u, y = _record()
    est = pj.ContinuousRLS(1e4, DT)
    res = estimate_record(est, u, y, R, dt=DT, window=50, chunk=chunk)
    # The reference: the whole regressor at once, scaled as the streamed run scales it.
    a, b = np.max(np.abs(u)), np.max(np.abs(y))
    H = np.column_stack([ref.play(u, R, np.full(4, u[0])) / a, np.ones(len(u))])
    whole = pj.estimate(est, jnp.asarray(H), jnp.asarray(y / b))
    w_ref = np.asarray(whole.weights[-1]) * b / np.r_[np.full(4, a), 1.0]
    tol = dict(rtol=2e-4, atol=2e-4 * np.max(np.abs(w_ref)))
    assert np.allclose(res.weights, w_ref[:4], **tol) and np.isclose(res.offset, w_ref[4], **tol)
    # The kept trajectory is the reference's at the kept instants.
    k = np.round(np.asarray(res.t) / DT).astype(int)
    assert k[-1] == len(u) - 1
    assert np.allclose(
        res.weights_trajectory, np.asarray(whole.weights)[k, :4] * b / a, rtol=2e-4, atol=2e-4 * np.max(np.abs(w_ref))
    )
    # PE levels and the certificate, window by window, as the whole-record functions give them.
    levels = pj.windowed_pe_levels(jnp.asarray(H), 50, stride=50)
    assert np.allclose(res.pe_levels, levels, rtol=1e-3, atol=1e-7)
    cert = pj.convergence_certificate(jnp.asarray(H), 1e4, DT, 50)
    ends = np.arange(1, len(levels) + 1) * 50 - 1
    assert np.allclose(res.gram_bound, np.asarray(cert.gram_bound)[ends], rtol=1e-3)
    assert np.allclose(res.bound_t, ends * DT)


def test_final_weights_recover_a_noise_free_model():
    u, y = _record(n=3000)
    res = estimate_record(pj.ContinuousRLS(1e10, DT), u, y, R, dt=DT)
    assert np.allclose(res.weights, W, rtol=1e-3, atol=1e-3) and abs(float(res.offset) - 0.5) < 1e-3
    assert res.final_rmse < 1e-3
    assert np.all(res.exciting)
    # final_rmse is the RMSE of the model with the final weights over the record.
    pred = ref.play(u, R, np.full(4, u[0])) @ np.asarray(res.weights) + float(res.offset)
    assert res.final_rmse == pytest.approx(np.sqrt(np.mean((pred - y) ** 2)), rel=1e-4, abs=1e-9)


def test_start_carries_the_play_states_through_the_skipped_samples():
    u, y = _record(noise=0.01)
    k = 237
    est = pj.ForgettingRLS(1e3, 0.999)
    skipped = estimate_record(est, u, y, R, dt=DT, start=k, window=60)
    x_k = ref.play(u[: k + 1], R, np.full(4, u[0]))[k - 1]
    direct = estimate_record(est, u[k:], y[k:], R, dt=DT, initial_states=x_k, window=60)
    assert np.allclose(skipped.weights, direct.weights, rtol=1e-5, atol=1e-6)
    assert np.allclose(skipped.initial_states, x_k)
    assert skipped.final_rmse == pytest.approx(direct.final_rmse, rel=1e-5)
    assert float(skipped.t[0]) == pytest.approx(k * DT)
    # Only the continuous RLS has a certificate.
    assert skipped.gram_bound.size == 0


def test_settled_start():
    u = np.concatenate([np.zeros(100), np.sin(np.linspace(0, 6 * np.pi, 600))])
    k = settled_start(u)
    # The input comes within 2 % of its range (0.04) of its maximum after a quarter period and
    # of its minimum after three quarters: the second of those is the start.
    assert u[:k].max() >= 0.96 and u[k] <= -0.96 and u[:k].min() > -0.96
    assert 100 + 150 - 15 < k < 100 + 150
    assert settled_start(np.linspace(0, 1, 50)) == 0  # one sweep of the whole record: no skip
    assert settled_start(np.ones(10)) == 0
    for bad in (np.inf, np.nan):
        with pytest.raises(ValueError, match="`u` must be finite to find where the plays settle"):
            settled_start(np.array([0.0, 1.0, bad, 0.5]))


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(thresholds=[[0.0, 1.0]]), "vector"),
        (dict(window=1), "window"),
        (dict(start=899), "start"),
        (dict(initial_states=[0.0, 1.0]), "initial_states"),
        (dict(dt=0.0), "dt"),
    ],
)
def test_bad_arguments_are_named(kwargs, match):
    u, y = _record()
    args = dict(thresholds=R, dt=DT) | kwargs
    with pytest.raises(ValueError, match=match):
        estimate_record(pj.ContinuousRLS(1e4, DT), u, y, args.pop("thresholds"), **args)
    with pytest.raises(ValueError, match="the model has 5"):
        estimate_record(pj.ContinuousRLS(jnp.eye(3), DT), u, y, R, dt=DT)


def _csv(tmp_path, n=2000):
    u, y = _record(n=n, noise=0.005)
    p = tmp_path / "rec.csv"
    p.write_text("t,u,y\n" + "\n".join(f"{i * DT},{a},{c}" for i, (a, c) in enumerate(zip(u, y))))
    return p


def test_cli_writes_the_report(tmp_path, capsys):
    p = _csv(tmp_path)
    out = tmp_path / "est"
    assert main(["estimate", str(p), "--thresholds", "0,0.4,0.9,1.5", "--out", str(out), "--start", "0"]) == 0
    rep = json.loads((out / "estimate.json").read_text())
    assert np.allclose(rep["weights_final"], W, rtol=0.05) and abs(rep["offset_final"] - 0.5) < 0.05
    assert rep["final_rmse"] < 0.01 and rep["pe"]["all_exciting"] and rep["start_time"] == 0.0
    assert len(rep["trajectory"]["t"]) == 2000 and len(rep["certificate"]["gram_bound"]) == 10
    assert (out / "estimate.png").stat().st_size > 0
    # The library call gives the same numbers.
    u, y = np.loadtxt(p, delimiter=",", skiprows=1)[:, 1:].T
    # The command computes in float64; the library call does too here, and the setting the
    # worker had is restored after.
    before = jax.config.jax_enable_x64
    jax.config.update("jax_enable_x64", True)
    try:
        res = estimate_record(pj.ContinuousRLS(1e8, DT), u, y, R, dt=DT)
    finally:
        jax.config.update("jax_enable_x64", before)
    assert np.allclose(rep["weights_final"], res.weights, rtol=1e-9)
    # Everything but the command's own keys is the library result's to_json.
    want = json.loads(pj.write_json(tmp_path / "lib.json", res.to_json()).read_text())
    assert set(rep) - set(want) == {"data", "estimator", "settings", "offset_estimated"}
    _assert_close_tree({k: rep[k] for k in want}, want)


def _assert_close_tree(a, b, path="report"):
    if isinstance(b, dict):
        assert isinstance(a, dict) and a.keys() == b.keys(), path
        for k in b:
            _assert_close_tree(a[k], b[k], f"{path}.{k}")
    else:
        np.testing.assert_allclose(np.asarray(a, float), np.asarray(b, float), rtol=1e-9, atol=1e-12, err_msg=path)


@pytest.mark.parametrize(
    "extra, match",
    [
        (["--thresholds", "1,0.5"], "start at 0 and increase"),
        (["--estimator", "forgetting", "--forgetting", "2"], "(0, 1]"),
        (["--forgetting", "0.5"], "--forgetting is a setting of --estimator forgetting, not of --estimator rls"),
        (["--start", "-1"], "time >= 0"),
        (["--start", "99"], "fewer than 2 samples"),
        (["--from-fit", "nope.json"], "--from-fit: nope.json: no such file"),
        (["--window", "1000"], "--window"),
    ],
)
def test_cli_bad_options_are_one_line(tmp_path, capsys, extra, match):
    p = _csv(tmp_path, n=300)
    assert main(["estimate", str(p), "--out", str(tmp_path / "o"), *extra]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and match in err
    assert not (tmp_path / "o" / "estimate.json").exists()
