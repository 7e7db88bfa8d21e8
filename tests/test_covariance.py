"""The fit's parameter covariance: Jacobian against finite differences of the NumPy reference,
closed-form regression covariance, rank deficiency named, calibration over noise draws."""

import jax
import numpy as np
import pytest
import reference as ref
from test_creep import reference_lags

import piest_jax as pj
from piest_jax._identification import covariance as _cov
from piest_jax._identification import fit as _fit
from piest_jax._identification.fit_data import Scales

pytestmark = pytest.mark.long

R, W = np.array([0.0, 0.4, 0.9]), np.array([1.0, 0.6, 0.5])


def signal(T=300):
    t = np.linspace(0.0, 2.0, T)
    return 1.5 * np.sin(2 * np.pi * 2 * t) * (1 - 0.2 * t)


def reference_model(u, theta, names, dt, x0, z0):
    """Output of PI + creep + offset from named parameters, by the NumPy loops."""
    get = dict(zip(names, theta))
    n = sum(k.startswith("weights[") for k in names)
    k = sum(k.startswith("creep.weights[") for k in names)
    r = np.array([0.0] + [get[f"thresholds[{j}]"] for j in range(1, n)])
    w = np.array([get[f"weights[{j}]"] for j in range(n)])
    x = np.array([x0[0]] + [get.get(f"initial_states[{j}]", x0[j]) for j in range(1, n)])
    y = ref.play(u, r, x) @ w + get["offset"]
    if k:
        tau = np.array([get[f"creep.time_constants[{j}]"] for j in range(k)])
        c = np.array([get[f"creep.weights[{j}]"] for j in range(k)])
        z = np.array([get.get(f"creep.initial_states[{j}]", z0[j]) for j in range(k)])
        y = y + reference_lags(u, tau, dt, z) @ c
    return y


def model_setup(T, states, lags):
    """A record, scales, a layout and its parameters in the data's units, for the Jacobian tests."""
    u = signal(T) + 0.7
    s = Scales(*(np.float64(v) for v in (0.5, 1.6, -0.2, 2.5)))
    layout = _cov.Layout(3, lags, states)
    x0 = np.array([u[0], u[0] + 0.1, u[0] - 0.3])
    z0 = np.full(lags, u[0] - 0.2)
    parts = dict(thresholds=R, weights=W, offset=0.3)
    if states:
        parts["states"] = x0
    if lags:
        parts.update(taus=np.array([0.05, 0.4]), lag_weights=np.array([0.3, -0.2]), lag_states=z0 + 0.1)
    theta = np.asarray(_cov.flatten(layout, **{k: np.asarray(v, float) for k, v in parts.items()}))
    return u, s, layout, x0, z0, theta


@pytest.mark.parametrize("states, lags", [(False, 0), (True, 0), (True, 2)])
def test_jacobian_matches_finite_differences(states, lags):
    dt = 0.01
    u, s, layout, x0, z0, theta = model_setup(200, states, lags)
    names, index = layout.names(3, lags)
    assert index.tolist() == [i for i in range(theta.size) if not (states and i == 6)]
    un = (u - s.u_mid) / s.u_half
    pred, J = _cov.jacobian(_fit.run, layout, theta, un, s, (x0 - s.u_mid) / s.u_half, (z0 - s.u_mid) / s.u_half, dt)
    full = list(layout.sizes())
    all_names = [f"{n}[{j + (n == 'thresholds')}]" if n != "offset" else n for n, m in full for j in range(m)]
    np.testing.assert_allclose(pred, reference_model(u, theta, all_names, dt, x0, z0), atol=1e-12)
    eps = 1e-6
    for i in index:
        h = np.zeros_like(theta)
        h[i] = eps
        fd = (
            reference_model(u, theta + h, all_names, dt, x0, z0) - reference_model(u, theta - h, all_names, dt, x0, z0)
        ) / (2 * eps)
        np.testing.assert_allclose(np.asarray(J)[:, i], fd, atol=1e-6, err_msg=all_names[i])


def test_gauss_newton_is_the_regression_covariance_given_the_thresholds():
    # With the thresholds held at their estimates the model is linear in (weights, offset): the
    # covariance of those conditional on the thresholds (a Schur complement of the joint one) is
    # the textbook σ² (AᵀA)⁻¹ with A = [H, 1] built by the NumPy play loop.
    u = signal()
    y = ref.play(u, R, u[0]) @ W + 0.3 + 0.02 * np.random.default_rng(0).standard_normal(u.size)
    f = pj.fit_pi(u, y, 3, thresholds0=R, n_starts=1, covariance="gauss-newton")
    assert f.parameter_names == ("thresholds[1]", "thresholds[2]", "weights[0]", "weights[1]", "weights[2]", "offset")
    S = np.asarray(f.covariance)
    t, lin = slice(0, 2), slice(2, 6)
    cond = S[lin, lin] - S[lin, t] @ np.linalg.solve(S[t, t], S[t, lin])
    A = np.column_stack([ref.play(u, np.asarray(f.thresholds), u[0]), np.ones(u.size)])
    e = y - A @ np.asarray(f.parameter_values)[lin]
    sigma2 = e @ e / (u.size - 6)
    np.testing.assert_allclose(cond, sigma2 * np.linalg.inv(A.T @ A), rtol=1e-6)
    np.testing.assert_allclose(f.std_errors, np.sqrt(np.diag(S)), rtol=1e-12)


def test_estimate_on_a_linear_regression():
    rng = np.random.default_rng(1)
    A = np.column_stack([rng.standard_normal(50), np.ones(50)])
    e = rng.standard_normal(50)
    cov, se, bad, info = _cov.estimate(A, e, method="gauss-newton")
    np.testing.assert_allclose(cov, e @ e / 48 * np.linalg.inv(A.T @ A), rtol=1e-12)
    assert not bad.any() and info["rank"] == 2
    # Newey-West with a block of one sample is White's sandwich; on these white residuals the
    # plug-in block is short.
    nw, _, _, info = _cov.estimate(A, e, method="newey-west")
    assert info["bandwidth"] <= 3
    B = np.linalg.inv(A.T @ A)
    assert np.allclose(np.diag(nw), np.diag(cov), rtol=0.5)
    if info["bandwidth"] == 1:
        np.testing.assert_allclose(nw, B @ (A.T * e**2) @ A @ B * 50 / 48, rtol=1e-12)
    with pytest.raises(ValueError, match="unknown covariance method 'x'"):
        _cov.estimate(A, e, method="x")


@pytest.mark.parametrize("method", _cov.METHODS)
@pytest.mark.parametrize("delta", [1e-2, 1e-6, 1e-8, 1e-10])
def test_nearly_collinear_columns_keep_their_variances(method, delta):
    # J = Jw M with Jw well conditioned and M exact: two pairs of columns a `delta` apart (J's
    # scaled condition number about 1/delta, full rank), so the covariance is M⁻¹ Cov_w M⁻ᵀ,
    # and the offset's column, which M leaves alone, keeps its variance.
    # Formed as (JᵀJ)⁻¹ Jᵀ Ω J (JᵀJ)⁻¹ in the parameters' coordinates, the variances came out
    # negative from delta = 1e-8 on (the offset's too) and were read as zero standard errors.
    N = 4000
    t = np.linspace(0.0, 1.0, N)
    x = np.sin(7 * t) + 0.3 * t
    e = np.convolve(np.random.default_rng(0).standard_normal(N + 50), np.ones(50) / 50, "valid")[:N] * 0.1
    Jw = np.column_stack([x, np.cos(31 * t), np.ones(N), x**2, t])
    M = np.eye(5)
    M[0, 1], M[1, 1], M[3, 4], M[4, 4] = 1.0, delta, 1.0, delta
    want, _, _, info_w = _cov.estimate(Jw, e, method=method)
    Minv = np.linalg.inv(M)
    want = Minv @ want @ Minv.T
    cov, se, bad, info = _cov.estimate(Jw @ M, e, method=method)
    assert info["rank"] == 5 and not bad.any() and info["bandwidth"] == info_w["bandwidth"]
    assert np.all(np.diag(cov) > 0) and np.all(np.isfinite(se))
    # Rounding of a matrix of condition number 1/delta, with a margin of 100.
    np.testing.assert_allclose(np.diag(cov), np.diag(want), rtol=100 * np.finfo(float).eps / delta)
    # The long-record path from triangular factors of J and of the block sums, as `moments`
    # accumulates them: the same covariance, to the factors' accuracy (from Σ W Wᵀ itself the
    # error grows like 1/delta², 3e3 eps/delta at delta = 1e-2 and 1.6e11 at 1e-10).
    J = Jw @ M
    b = info["bandwidth"] or 1
    cs = np.concatenate([np.zeros((1, 5)), np.cumsum(J * e[:, None], axis=0)])
    Rw = np.linalg.qr(cs[b:] - cs[:-b], mode="r")
    long, _, bad, info = _cov.estimate_moments(np.linalg.qr(J, mode="r"), Rw, e @ e, N, method=method, window=b)
    assert info["rank"] == 5 and not bad.any()
    # The factors' rounding grows like a sum of N terms (`estimate_moments`' rank floor): √N·eps.
    np.testing.assert_allclose(np.diag(long), np.diag(want), rtol=10 * np.sqrt(N) * np.finfo(float).eps / delta)


def test_rank_deficient_parameters_are_named_not_nan():
    # Columns 1 and 2 are collinear and column 3 is zero: three undetermined, one determined.
    rng = np.random.default_rng(2)
    a = rng.standard_normal(40)
    J = np.column_stack([rng.standard_normal(40), a, 2 * a, np.zeros(40)])
    cov, se, bad, info = _cov.estimate(J, rng.standard_normal(40))
    assert bad.tolist() == [False, True, True, True] and info["rank"] == 2
    assert np.all(np.isfinite(cov)) and np.isfinite(se[0]) and np.all(np.isinf(se[1:]))


def test_unexcited_play_is_undetermined_and_json_is_null(tmp_path):
    t = np.linspace(0.0, 2.0, 400)
    u = np.sin(2 * np.pi * 2 * t)  # thresholds >= 1 are never traversed
    y = ref.play(u, [0.0, 0.4], 0.0) @ [1.0, 0.5] + 0.01 * np.random.default_rng(3).standard_normal(400)
    f = pj.fit_pi(u, y, 3, thresholds0=[0.0, 0.4, 1.5], initial_states=0.0)
    assert f.flagged.tolist() == [False, False, True]
    assert "weights[2]" in f.undetermined_names and "thresholds[2]" in f.undetermined_names
    assert "weights[0]" not in f.undetermined_names
    assert np.all(np.isfinite(f.covariance))
    rep = pj.write_json(tmp_path / "f.json", {"std_errors": dict(zip(f.parameter_names, f.std_errors))})
    text = rep.read_text()
    assert "NaN" not in text and "Infinity" not in text


def near_top_record(T=700, seed=0):
    """The Chandra case in miniature: a sine from rest whose top play's threshold sits 0.2 % below
    the input's half range, so that the play moves by at most 0.2 % of it, yet carries the
    largest weight."""
    t = np.linspace(0.0, 3.5, T)
    u = np.sin(2 * np.pi * t)
    half = 0.5 * np.ptp(u)
    r = np.array([0.0, 0.3 * half, 0.998 * half])
    y = ref.play(u, r, u[0]) @ [1.0, 0.6, 1.5] + 0.02 * np.random.default_rng(seed).standard_normal(T)
    return u, y, r


def test_scales_of_the_relative_error_limit():
    names = ("thresholds[1]", "thresholds[2]", "weights[0]", "offset", "creep.time_constants[0]")
    names += ("creep.weights[0]", "creep.weights[1]", "initial_states[1]")
    values = (0.3, 0.9, 5.0, -0.2, 20.0, 3.0, 0.01, 0.5)
    got = _cov.scales(names, values, u_half=1.2, y_half=0.6)
    slope = 0.6 / 1.2
    # Threshold: the room below it or up to the top of the input's half range; a play weight: the
    # slope, however large the weight; a creep weight: the slope or its own size, the larger (a lag
    # slower than the record drifts with a weight well above the slope, known to a fraction of it).
    want = (0.3, 1.2 - 0.9, slope, 0.6, 20.0, 3.0, slope, 1.2)
    np.testing.assert_allclose(got, want, rtol=1e-12)


def test_play_at_the_top_of_the_range_is_undetermined():
    u, y, r = near_top_record()
    f = pj.fit_pi(u, y, 3, thresholds0=r, n_starts=1)
    assert bool(f.flagged[2]) and not np.any(np.asarray(f.flagged[:2]))
    assert set(f.undetermined_names) == {"thresholds[2]", "weights[2]"}


def test_model_size_never_keeps_an_undetermined_parameter():
    # With no tolerance the three-play candidate, whose top play the record barely moves, has the
    # best held-out score; it is rejected, and the two-play model kept.
    u, y, _ = near_top_record()
    opts = dict(tolerance=0.0, key=jax.random.key(0))
    a = pj.select_plays(u, y, (1, 2, 3), patience=None, **opts)
    b = pj.select_model(u, y, 0.005, (1, 2, 3), (0,), **opts)
    assert a.scores[2] < a.scores[1] and b.scores[2] < b.scores[1]
    assert a.rejected == (3,) and b.rejected == ((3, 0),)
    for sel in (a, b):
        assert sel.n_plays == 2 and sel.fit.determined and sel.fit.undetermined_names == ()


def test_the_only_candidate_is_kept_undetermined_and_not_listed_as_rejected():
    # With nothing else to offer, the choice keeps the undetermined model (its fit says so) and
    # `rejected` lists only candidates not chosen.
    u, y, _ = near_top_record()
    ch = pj.select_model(u, y, 0.005, (3,), (0,), key=jax.random.key(0))
    assert (ch.n_plays, ch.n_lags) == (3, 0) and ch.rejected == ()
    assert not ch.fit.determined and "thresholds[2]" in ch.fit.undetermined_names


@pytest.mark.optimized
@pytest.mark.parametrize("method", _cov.METHODS)
def test_calibration_over_noise_draws(method):
    # 200 white-noise draws: the sample standard deviation of each estimate is then known to
    # about 1/sqrt(2 * 199) = 5 %, so the 0.8-1.25 band on (mean predicted std error) / (spread)
    # is more than 4 of its standard errors wide on either side for each of the 6 parameters.
    # Starting at the true thresholds keeps each fit short; it converges to the least-squares
    # optimum of its own draw all the same.
    u = signal()
    y0 = ref.play(u, R, u[0]) @ W + 0.3
    noise = 0.01 * np.ptp(y0) * np.random.default_rng(11).standard_normal((200, u.size))
    est, se = [], []
    for e in noise:
        f = pj.fit_pi(u, y0 + e, 3, thresholds0=R, n_starts=1, covariance=method)
        est.append(np.asarray(f.parameter_values))
        se.append(np.asarray(f.std_errors))
    ratio = np.mean(se, axis=0) / np.std(est, axis=0, ddof=1)
    assert np.all((0.8 < ratio) & (ratio < 1.25)), dict(zip(f.parameter_names, ratio))


def test_bad_covariance_name():
    u = signal()
    with pytest.raises(ValueError, match="unknown covariance 'sandwich'"):
        pj.fit_pi(u, u, 2, covariance="sandwich")


def test_creep_parameters_have_standard_errors():
    from test_fit_creep import DT, plant
    from test_fit_creep import signal as creep_signal

    u = creep_signal(600)
    y = plant(u) + 0.002 * np.random.default_rng(5).standard_normal(u.size)
    f = pj.fit_pi(u, y, 3, n_lags=1, dt=DT, fit_initial_states=True, key=jax.random.key(0))
    assert f.parameter_names[-3:] == ("creep.time_constants[0]", "creep.weights[0]", "creep.initial_states[0]")
    assert "initial_states[0]" not in f.parameter_names and "initial_states[2]" in f.parameter_names
    se = dict(zip(f.parameter_names, np.asarray(f.std_errors)))
    assert 0 < se["creep.time_constants[0]"] < 0.1 * float(f.creep.time_constants[0])
    assert np.all(np.isfinite(f.covariance)) and f.covariance.shape == (len(f.parameter_names),) * 2
    # Without covariance the fit is the same and the fields are empty.
    g = pj.fit_pi(u, y, 3, n_lags=1, dt=DT, fit_initial_states=True, key=jax.random.key(0), covariance=None)
    assert g.covariance is None and g.parameter_names == () and g.undetermined_names == ()
    np.testing.assert_allclose(g.thresholds, f.thresholds, rtol=1e-12)


def test_cli_writes_null_std_errors_and_names_undetermined(tmp_path, capsys, monkeypatch):
    import json

    from piest_jax._cli import main
    from piest_jax._identification import identify as identify_module

    t = np.linspace(0.0, 2.0, 400)
    u = np.sin(2 * np.pi * 2 * t)
    y = ref.play(u, [0.0, 0.4], 0.0) @ [1.0, 0.5] + 0.01 * np.random.default_rng(3).standard_normal(400)
    np.savetxt(tmp_path / "d.csv", np.column_stack([t, u, y]), delimiter=",", header="t,u,y", comments="")
    real = pj.fit_pi
    # The solver would move a play out of reach; starting it there and taking no step keeps it.
    monkeypatch.setattr(
        identify_module,
        "fit_pi",
        lambda u, y, n, **kw: real(u, y, n, thresholds0=[0.0, 0.4, 1.5], n_starts=1, max_steps=1, initial_states=0.0),
    )
    out = tmp_path / "o"
    assert main(["fit", str(tmp_path / "d.csv"), "--model", "pi", "--plays", "3", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    text = (out / "fit.json").read_text()
    rep = json.loads(text)
    assert "NaN" not in text and "Infinity" not in text
    assert rep["std_errors"]["thresholds[2]"] is None and rep["std_errors"]["weights[0]"] > 0
    assert "std_errors.thresholds[2]" in rep["non_finite"]
    assert "thresholds[2]" in rep["undetermined"] and rep["flagged"][2] is True
    assert "does not determine" in err and "thresholds[2]" in err and "| weights[0] |" in err
    assert "undetermined (rank)" in (out / "fit.md").read_text()
    assert pj.load_model(out / "fit.json").pi.thresholds.shape == (3,)


def test_a_long_float32_record_keeps_its_rank():
    # The chunked factor's rounding grows like a sum's, so the rank floor is sqrt(N) eps, not
    # N eps: a float32 fit on 10^6 samples whose Jacobian has condition ~40 is determined, and a
    # column that repeats another is still free.
    rng = np.random.default_rng(5)
    N = 10**6
    J = rng.standard_normal((N, 4)) @ np.array([[1, 1, 0, 0], [0, 0.05, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])
    e = rng.standard_normal(N)
    eps32 = np.finfo(np.float32).eps
    R = np.linalg.qr(J, mode="r")
    assert N * eps32 > 1 / np.linalg.cond(J / np.linalg.norm(J, axis=0))  # the old floor would drop it
    _, se, deficient, info = _cov.estimate_moments(
        R, np.eye(4), float(e @ e), N, method="gauss-newton", window=1, eps=eps32
    )
    assert info["rank"] == 4 and not deficient.any() and np.all(np.isfinite(se))
    R2 = np.linalg.qr(np.column_stack([J, J[:, 0]]), mode="r")
    _, se2, deficient2, info2 = _cov.estimate_moments(
        R2, np.eye(5), float(e @ e), N, method="gauss-newton", window=1, eps=eps32
    )
    assert info2["rank"] == 4 and deficient2.tolist() == [True, False, False, False, True]


@pytest.mark.parametrize("method", _cov.METHODS)
@pytest.mark.parametrize("states, lags", [(False, 0), (True, 2)])
def test_long_records_give_the_dense_estimate_in_bounded_memory(method, states, lags):
    # The chunked moments (J's rows a chunk at a time, states and sensitivities carried) against
    # J held whole, on a record of 1000 samples cut into chunks of 64 (not a multiple).
    rng = np.random.default_rng(3)
    dt = 0.01
    u, s, layout, x0, z0, theta = model_setup(1000, states, lags)
    names, index = layout.names(3, lags)
    un = (u - s.u_mid) / s.u_half
    xn, zn = (x0 - s.u_mid) / s.u_half, (z0 - s.u_mid) / s.u_half
    pred, J = _cov.jacobian(_fit.run, layout, theta, un, s, xn, zn, dt)
    # Smooth (coloured) residuals, so that the Newey-West blocks are longer than one sample.
    e = np.convolve(rng.standard_normal(1000 + 20), np.ones(20) / 20, "valid")[:1000] * 0.05
    y = np.asarray(pred) + e
    mask = np.ones(1000)
    want = _cov.estimate(np.asarray(J)[:, index], e, method=method)
    window = _cov.bandwidth(e) if method == "newey-west" else 1
    assert method == "gauss-newton" or window > 2
    R, Rw, ete = _cov.moments(_fit.run, layout, theta, un, y, mask, s, xn, zn, dt, window, 64)
    np.testing.assert_allclose(np.asarray(R).T @ np.asarray(R), np.asarray(J).T @ np.asarray(J), rtol=1e-10, atol=1e-10)
    if method == "newey-west":  # Rw is a factor of the block sums' Σ W Wᵀ
        g = np.asarray(J) * e[:, None]
        cs = np.concatenate([np.zeros((1, g.shape[1])), np.cumsum(g, axis=0)])
        W = cs[window:] - cs[:-window]
        np.testing.assert_allclose(np.asarray(Rw).T @ np.asarray(Rw), W.T @ W, rtol=1e-10, atol=1e-12)
    got = _cov.estimate_moments(
        np.asarray(R)[:, index],
        np.asarray(Rw)[:, index],
        float(ete),
        1000,
        method=method,
        window=window,
    )
    # A bound that holds for the factor and for JᵀJ alike (which lose cond(J) and cond(J)^2 eps).
    Js = np.asarray(J)[:, index] / np.linalg.norm(np.asarray(J)[:, index], axis=0)
    rtol = 10 * np.linalg.cond(Js) ** 2 * np.finfo(float).eps
    assert rtol < 1e-5
    scale = np.sqrt(np.outer(np.diag(want[0]), np.diag(want[0])))
    np.testing.assert_array_less(np.abs(got[0] - want[0]), rtol * scale + 1e-300)
    np.testing.assert_allclose(got[1], want[1], rtol=rtol)
    assert not got[2].any() and not want[2].any()


@pytest.mark.parametrize("block", [1, 7, 64, 1000])
def test_blocked_lag_sums_give_the_whole_records_block_length(block):
    # The long-record pass sums e² and e_t e_(t-1) a block at a time, pairing consecutive used
    # samples across blocks and held-out gaps, as `bandwidth` does on the selected residuals.
    rng = np.random.default_rng(3)
    T = 500
    y = np.cumsum(rng.standard_normal(T)) * 0.1  # correlated, so rho and the block length matter
    pred = 0.05 * rng.standard_normal(T)
    mask = rng.uniform(0.5, 1.5, T)
    mask[rng.uniform(size=T) < 0.3] = 0.0  # holes
    mask[:20] = 0.0
    used = mask > 0
    e = (y - pred)[used] * mask[used]
    den, cross, n = _cov._lag_sums(y, pred, mask, block)
    assert n == e.size
    assert den == pytest.approx(float(e @ e), rel=1e-12)
    assert cross == pytest.approx(float(e[1:] @ e[:-1]), rel=1e-12)
    assert _cov.bandwidth_of(den, cross, n) == _cov.bandwidth(e)
    assert _cov.bandwidth(e) > 1
