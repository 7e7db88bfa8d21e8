"""Threshold fitting: recovery of known operators, gradients, rate independence, identifiability."""

import jax
import jax.flatten_util
import jax.numpy as jnp
import numpy as np
import pytest
from reference import pi as reference_pi  # a plain loop, independent of the library

import piest_jax as pj
from piest_jax._identification import fit as _fit
from piest_jax._identification.holdout import holdout_mask, padded_plays

pytestmark = pytest.mark.long

R_TRUE = np.array([0.0, 0.5, 1.2])
W_TRUE = np.array([1.0, 0.6, 0.4])
C_TRUE = 0.3
T = 400


def record(T=T):
    t = np.linspace(0.0, 2.0, T)
    # A decaying sine with an offset: major and minor loops, and an input that does not start at 0.
    u = 1.0 + 3.0 * np.sin(2 * np.pi * 2 * t) * (1 - 0.2 * t)
    y = reference_pi(u, R_TRUE, W_TRUE, u[0]) + C_TRUE
    return u, y


@pytest.fixture(scope="module")
def clean():
    u, y = record()
    return u, y, pj.fit_pi(u, y, 3, key=jax.random.key(0))


@pytest.fixture(scope="module")
def noisy():
    u, y = record()
    noise = 0.01 * np.ptp(y) * np.random.default_rng(7).standard_normal(len(y))
    return u, y + noise, pj.fit_pi(u, y + noise, 3, key=jax.random.key(0))


def test_recovers_noise_free(clean):
    u, y, f = clean
    assert f.result_name == "successful"
    np.testing.assert_allclose(f.thresholds, R_TRUE, atol=0.01 * np.ptp(u))
    np.testing.assert_allclose(f.thresholds, R_TRUE, atol=1e-6)
    np.testing.assert_allclose(f.weights, W_TRUE, rtol=1e-5)
    assert abs(float(f.offset) - C_TRUE) < 1e-5
    assert float(f.rmse) < 1e-8 * np.ptp(y)
    assert not np.any(f.flagged)
    # The fitted model reproduces the data through the public operator as well.
    np.testing.assert_allclose(f(u), y, atol=1e-7)


def test_recovers_noisy(noisy):
    # Noise of 1 % of the output range. Weights of neighbouring plays trade off against each other
    # (even with the true thresholds held fixed, least squares moves them by ~5 % here), so the
    # stated tolerances are: thresholds within 3 % of the input range, weights within 15 %.
    u, y, f = noisy
    np.testing.assert_allclose(f.thresholds, R_TRUE, atol=0.03 * np.ptp(u))
    np.testing.assert_allclose(f.weights, W_TRUE, rtol=0.15)
    # The fit is at least as good as the true parameters (it found the best fit, not a local one).
    truth = np.sqrt(np.mean((reference_pi(u, R_TRUE, W_TRUE, u[0]) + C_TRUE - y) ** 2))
    assert float(f.rmse) <= truth * (1 + 1e-9)
    assert float(f.rmse) > 0.5 * truth


def test_units_are_restored(clean):
    # Affine changes of units map onto the parameters: r scales with u, w with y/u.
    u, y, f = clean
    g = pj.fit_pi(5.0 + 10.0 * u, 1000.0 * y - 2.0, 3, key=jax.random.key(0))
    np.testing.assert_allclose(g.thresholds, 10.0 * R_TRUE, atol=1e-5)
    np.testing.assert_allclose(g.weights, 100.0 * W_TRUE, rtol=1e-5)
    np.testing.assert_allclose(g.initial_states, 5.0 + 10.0 * u[0], rtol=1e-12)
    np.testing.assert_allclose(g(5.0 + 10.0 * u), 1000.0 * y - 2.0, atol=1e-4)


def test_decimated_record_gives_same_thresholds(clean):
    # Rate independence: every second sample traces the same loops.
    u, y, f = clean
    g = pj.fit_pi(u[::2], y[::2], 3, key=jax.random.key(0))
    np.testing.assert_allclose(g.thresholds, f.thresholds, atol=0.01 * np.ptp(u))


def test_objective_gradient_matches_finite_differences():
    u, y = record(200)
    un = (u - u.mean()) / np.ptp(u)
    yn = (y - y.mean()) / np.ptp(y)
    key = jax.random.key(3)
    params = {
        "increments": jax.random.normal(key, (2,)) * 0.3 - 1.0,
        "weights": jax.random.normal(jax.random.key(4), (3,)),
        "offset": jnp.asarray(0.1),
        "initial_states": jnp.asarray([0.05, 0.0, -0.05]),
    }
    args = (jnp.asarray(un), jnp.asarray(yn), jnp.zeros(3), jnp.ones(200), True, None, None, None, None, None)

    @jax.jit
    def loss(p):
        return jnp.sum(_fit._residuals(p, args) ** 2)

    grad = jax.grad(loss)(params)
    flat, unravel = jax.flatten_util.ravel_pytree(params)
    g_flat = jax.flatten_util.ravel_pytree(grad)[0]
    eps = 1e-6
    fd = np.array(
        [
            (loss(unravel(flat.at[i].add(eps))) - loss(unravel(flat.at[i].add(-eps)))) / (2 * eps)
            for i in range(flat.shape[0])
        ]
    )
    np.testing.assert_allclose(g_flat, fd, rtol=1e-5, atol=1e-9)


def test_fit_derivative_matches_finite_differences():
    # d(fitted parameters)/d(data) through the solver (implicit differentiation at the optimum)
    # against central differences of complete re-fits, along one perturbation of the output.
    u, y = record()
    un, yn, mask, s, x0, _ = _fit._prepare(u, y, 3, None, None, None)
    pad = un.shape[0] - T
    d = np.concatenate([np.random.default_rng(1).standard_normal(T), np.zeros(pad)])
    d = jnp.asarray(d) / s.y_half
    r0s = _fit._grid(3, 1, un.dtype, None)
    static = dict(solver="lm", positive_weights=True, fit_initial_states=False, max_steps=100, rtol=1e-6, atol=1e-9)

    def fitted(eps):
        p, _, results, _ = _fit._solve_starts(r0s, un, yn + eps * d, x0, mask, None, **static)
        r, w = _fit._constrained(jax.tree.map(lambda a: a[0], p), True)
        return jnp.concatenate([r[1:], w, p["offset"]]), results

    assert _fit.result_name(fitted(0.0)[1]) == "successful"
    jac = jax.jacfwd(lambda e: fitted(e)[0])(0.0)
    h = 1e-4
    fd = (fitted(h)[0] - fitted(-h)[0]) / (2 * h)
    assert np.all(np.abs(np.asarray(jac)) > 1e-3)  # a real sensitivity, not a zero gradient
    np.testing.assert_allclose(jac, fd, rtol=1e-5)


def test_reverse_mode_gradient_through_multistart_fit():
    # jax.grad of a scalar of the best start's fitted parameters w.r.t. the measured output, through
    # the vmapped multi-start solve, against central differences of complete re-fits.
    u, y = record()
    un, yn, mask, s, x0, _ = _fit._prepare(u, y, 3, None, None, None)
    r0s = _fit._grid(3, 2, un.dtype, jax.random.key(0))
    static = dict(solver="lm", positive_weights=True, fit_initial_states=False, max_steps=100, rtol=1e-6, atol=1e-9)
    coef = jnp.asarray([0.3, -0.7, 1.1, 0.5, -0.2, 0.9])

    @jax.jit
    def scalar(yy):
        p, loss, _, _ = _fit._solve_starts(r0s, un, yy, x0, mask, None, **static)
        p = jax.tree.map(lambda a: a[jnp.argmin(loss)], p)
        r, w = _fit._constrained(p, True)
        return jnp.dot(coef, jnp.concatenate([r[1:], w, p["offset"][None]]))

    grad = jax.grad(scalar)(yn)
    d = np.concatenate([np.random.default_rng(2).standard_normal(T), np.zeros(un.shape[0] - T)])
    d = jnp.asarray(d) / s.y_half
    h = 1e-4
    fd = (scalar(yn + h * d) - scalar(yn - h * d)) / (2 * h)
    assert abs(float(fd)) > 1e-3  # a real sensitivity
    np.testing.assert_allclose(float(jnp.dot(grad, d)), float(fd), rtol=1e-5)
    # Padded samples are masked out of the fit: the data there cannot move the result.
    np.testing.assert_array_equal(np.asarray(grad[T:]), 0.0)


def test_multistart_equals_single_starts(clean):
    u, y, f = clean
    grids = _fit._grid(3, 4, jnp.float64, jax.random.key(0))
    for k in (1, 3):
        single = pj.fit_pi(u, y, 3, thresholds0=np.asarray(grids[k]) * 0.5 * np.ptp(u))
        np.testing.assert_allclose(single.start_rmse[0], f.start_rmse[k], rtol=1e-6, atol=1e-12)
    assert float(f.rmse) == pytest.approx(float(np.min(f.start_rmse)))
    # Starts solved one after another (as for long records) give the same fits.
    seq = pj.fit_pi(u, y, 3, key=jax.random.key(0), starts_at_once=1)
    np.testing.assert_allclose(seq.start_rmse, f.start_rmse, rtol=1e-9, atol=1e-14)
    np.testing.assert_allclose(seq.thresholds, f.thresholds, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize(
    "options",
    [{}, {"max_threshold": 1.8, "fit_initial_states": True}, {"positive_weights": False, "solver": "gn"}],
    ids=["plain", "bounded_initial_states", "signed_gauss_newton"],
)
def test_padded_fit_equals_unpadded(noisy, options):
    # Inactive plays added to share a compilation change nothing but rounding: the same thresholds,
    # weights, offset, states and RMSE, for fits that converge and for one stopped by max_steps.
    u, y, _ = noisy
    for n, steps in ((3, 100), (3, 4)):
        a = pj.fit_pi(u, y, n, key=jax.random.key(1), max_steps=steps, **options)
        b = pj.fit_pi(u, y, n, key=jax.random.key(1), max_steps=steps, pad_plays=6, **options)
        assert b.thresholds.shape == b.weights.shape == b.initial_states.shape == (n,)
        assert a.result_name == b.result_name
        # Stopped after the same 4 steps, the two agree to rounding; converged, either may stop a
        # step earlier when rounding crosses the solver's rtol (1e-6), so they agree to that.
        tol = 1e-7 if steps == 4 else 1e-5
        if steps == 4:
            assert int(a.n_steps) == int(b.n_steps) == 4
        for name in ("thresholds", "weights", "offset", "start_rmse"):
            np.testing.assert_allclose(
                getattr(b, name), getattr(a, name), rtol=tol, atol=1e-9, err_msg=f"{name}, {n} plays, {steps} steps"
            )
        # The r = 0 play forgets its initial state at the first sample, so only the others count.
        np.testing.assert_allclose(b.initial_states[1:], a.initial_states[1:], rtol=tol, atol=1e-9)
        np.testing.assert_allclose(b(u), a(u), rtol=tol, atol=1e-9)


def test_unexcited_play_is_flagged():
    t = np.linspace(0.0, 2.0, T)
    u = np.sin(2 * np.pi * 2 * t)  # peak-to-peak 2: thresholds >= 1 are never traversed
    y = reference_pi(u, np.array([0.0, 0.4]), np.array([1.0, 0.5]), 0.0)
    f = pj.fit_pi(u, y, 3, thresholds0=[0.0, 0.4, 1.5])
    np.testing.assert_array_equal(f.flagged, [False, False, True])
    np.testing.assert_allclose(f.thresholds[:2], [0.0, 0.4], atol=0.01 * np.ptp(u))
    np.testing.assert_array_equal(pj.unexcited(u, [0.0, 0.99, 1.0, 2.0]), [False, False, True, True])


@pytest.mark.parametrize("solver", ["gn", "bfgs"])
def test_other_solvers_recover(solver):
    u, y = record()
    f = pj.fit_pi(u, y, 3, solver=solver, n_starts=1, max_steps=400)
    assert f.result_name == "successful"
    np.testing.assert_allclose(f.thresholds, R_TRUE, atol=0.01 * np.ptp(u))


def test_fits_initial_states():
    u, y0 = record()
    x0 = np.array([0.2, 0.6, 1.0])  # admissible, and not the default u[0]
    y = reference_pi(u, R_TRUE, W_TRUE, x0) + C_TRUE
    fixed = pj.fit_pi(u, y, 3, n_starts=1)
    free = pj.fit_pi(u, y, 3, fit_initial_states=True, n_starts=1)
    assert float(free.rmse) < 1e-3 * float(fixed.rmse) + 1e-9
    np.testing.assert_allclose(free.thresholds, R_TRUE, atol=0.01 * np.ptp(u))


def test_uniform_grid_matches_numpy_least_squares():
    u, y = record()
    n = 5
    r = np.arange(n) * 0.5 * np.ptp(u) / n
    H = np.stack([reference_pi(u, r[j : j + 1], np.ones(1), u[0]) for j in range(n)], axis=1)
    A = np.column_stack([H, np.ones(len(u))])
    coef = np.linalg.lstsq(A, y, rcond=None)[0]
    b = pj.uniform_pi(u, y, n)
    np.testing.assert_allclose(b.thresholds, r, rtol=1e-12)
    np.testing.assert_allclose(b.weights, coef[:n], rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(b.rmse, np.sqrt(np.mean((A @ coef - y) ** 2)), rtol=1e-6)


def test_model_size_selection(noisy):
    u, y, _ = noisy
    for criterion in ("holdout", "bic"):
        sel = pj.select_plays(u, y, (2, 3), criterion=criterion, n_starts=1)
        assert sel.n_plays == 3, (criterion, sel.scores)
        assert sel.scores[1] < sel.scores[0]
    # Early stop: 4 plays do not improve on 3, so with patience 1 the search ends there and 5 is
    # never fitted; candidates are tried smallest first whatever their order.
    sel = pj.select_plays(u, y, (4, 2, 5, 3), patience=1, n_starts=1)
    assert sel.candidates == (2, 3, 4) and sel.n_plays == 3, sel.scores
    # Short records: candidates share one compilation, padded to the largest; long ones do not.
    assert [padded_plays(n, 10, 8000) for n in (1, 4, 10)] == [10, 10, 10]
    assert [padded_plays(n, 10, 10**5) for n in (1, 4, 10)] == [1, 4, 10]
    mask = holdout_mask(10, 0.3)
    np.testing.assert_array_equal(mask, [1] * 7 + [0] * 3)


def test_model_size_selection_with_mask(noisy):
    # A start-up transient that no PI produces: masked out, it neither drives the choice nor the
    # fit (the plays still run through it), and the held-out score ignores it too.
    u, y, _ = noisy
    y = y.copy()
    y[:40] += 5.0 * np.ptp(y) * np.exp(-np.arange(40) / 8.0)
    used = np.ones(T)
    used[:40] = 0.0
    for criterion in ("holdout", "bic"):
        sel = pj.select_plays(u, y, (2, 3), criterion=criterion, n_starts=1, mask=used)
        assert sel.n_plays == 3, (criterion, sel.scores)
        np.testing.assert_allclose(sel.fit.thresholds, R_TRUE, atol=0.03 * np.ptp(u))
        ref = pj.fit_pi(u, y, 3, n_starts=1, mask=used)
        np.testing.assert_allclose(sel.fit.rmse, ref.rmse, rtol=1e-5)
    # The held-out block is scored only where the mask is 1: masking its last samples changes the
    # score to the RMSE over the remaining ones.
    tail = used.copy()
    tail[-20:] = 0.0
    a = pj.select_plays(u, y, (3,), n_starts=1, mask=tail)
    f = pj.fit_pi(u, y, 3, n_starts=1, mask=tail * holdout_mask(T, 0.3))
    test = (holdout_mask(T, 0.3) == 0) & (tail > 0)
    expected = np.sqrt(np.mean((np.asarray(f(u))[test] - y[test]) ** 2))
    assert a.scores[0] == pytest.approx(expected, rel=1e-6)
    with pytest.raises(ValueError, match=r"`mask` has shape \(10,\), expected \(400,\)"):
        pj.select_plays(u, y, (2,), mask=np.ones(10))
    with pytest.raises(ValueError, match="held-out block has no used samples"):
        pj.select_plays(u, y, (2,), mask=holdout_mask(T, 0.3))


def test_bad_requests():
    u, y = record()
    with pytest.raises(ValueError, match="parameters but only 10 samples"):
        pj.fit_pi(u[:10], y[:10], 6)
    with pytest.raises(ValueError, match="zero range"):
        pj.fit_pi(np.ones(50), y[:50], 2)
    with pytest.raises(ValueError, match="`u` has 400 samples but `y` has 399"):
        pj.fit_pi(u, y[:-1], 2)
    with pytest.raises(ValueError, match="`y` contains NaN"):
        pj.fit_pi(u, np.where(np.arange(T) == 5, np.nan, y), 2)
    # Huge but finite data: the message names the range, not NaN or inf.
    with pytest.raises(ValueError, match=r"`y` has values up to 1e\+307, out of the range"):
        pj.fit_pi(u, y * 1e307 / np.max(np.abs(y)), 2)
    with pytest.raises(ValueError, match="the input's range .* overflows float64"):
        pj.fit_pi(np.where(u > 1, 1.5e308, -1.5e308), y, 2)
    with pytest.raises(ValueError, match="unknown solver 'adam'"):
        pj.fit_pi(u, y, 2, solver="adam")
    with pytest.raises(ValueError, match="positive whole number"):
        pj.fit_pi(u, y, 0)
    with pytest.raises(ValueError, match="`thresholds0` must be 2 increasing thresholds"):
        pj.fit_pi(u, y, 2, thresholds0=[0.5, 1.0])
    with pytest.raises(ValueError, match="`pad_plays` must be a whole number of at least"):
        pj.fit_pi(u, y, 3, pad_plays=2)
    with pytest.raises(ValueError, match="`pad_plays` and `thresholds0` cannot be combined"):
        pj.fit_pi(u, y, 2, pad_plays=4, thresholds0=[0.0, 1.0])
    with pytest.raises(ValueError, match="unknown criterion"):
        pj.select_plays(u, y, (1, 2), criterion="aic")
    with pytest.raises(ValueError, match="`patience` must be a positive whole number"):
        pj.select_plays(u, y, (1, 2), patience=0)
    with pytest.raises(ValueError, match="`starts_at_once` must be a positive whole number"):
        pj.fit_pi(u, y, 2, starts_at_once=0)
    with pytest.raises(ValueError, match="distinct positive"):
        pj.select_plays(u, y, (0, 2))
    with pytest.raises(ValueError, match="strictly between 0 and 1"):
        holdout_mask(10, 1.0)


def write_record(path, u, y):
    t = np.arange(len(u)) * 0.005
    np.savetxt(path, np.column_stack([t, u, y]), delimiter=",", header="t,u,y", comments="")


def test_cli_fit(tmp_path, capsys, clean):
    from piest_jax._cli import main

    u, y, f = clean
    write_record(tmp_path / "d.csv", u, y)
    write_record(tmp_path / "v.csv", u[::2], y[::2])
    out = tmp_path / "out"
    rc = main(
        [
            "fit",
            str(tmp_path / "d.csv"),
            "--plays",
            "3",
            "--validate",
            str(tmp_path / "v.csv"),
            "--out",
            str(out),
            "--quiet",
        ]
    )
    assert rc == 0
    assert sorted(p.split("/")[-1] for p in capsys.readouterr().out.split()) == [
        "fit.json",
        "fit.md",
        "fit.png",
        "validation.png",
    ]
    rep = __import__("json").loads((out / "fit.json").read_text())
    np.testing.assert_allclose(rep["thresholds"], f.thresholds, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(rep["weights"], f.weights, rtol=1e-9)
    assert rep["solver"]["result"] == "successful"
    assert rep["rmse"] < 1e-8
    # Decimation can skip a turning point, so the validation record is not matched exactly; the
    # reported RMSE is the model's, computed here by the NumPy reference.
    yv = reference_pi(u[::2], np.asarray(f.thresholds), np.asarray(f.weights), u[0]) + f.offset
    expected = np.sqrt(np.mean((yv - y[::2]) ** 2))
    assert rep["validation_rmse"] == pytest.approx(expected, rel=1e-6, abs=1e-9)
    assert rep["validation_rmse"] < 1e-3 * np.ptp(y)
    assert rep["flagged"] == [False, False, False]
    # Every fitted parameter has a standard error by name, the covariance names its rows, and a
    # value +- std error table lands beside fit.json.
    names = ["thresholds[1]", "thresholds[2]", "weights[0]", "weights[1]", "weights[2]", "offset"]
    assert list(rep["std_errors"]) == names == rep["covariance"]["parameter_names"]
    assert rep["covariance"]["method"] == "newey-west" and rep["undetermined"] == []
    assert np.array(rep["covariance"]["matrix"]).shape == (6, 6)
    assert all(0 <= v < 1e-6 for v in rep["std_errors"].values())
    assert "| weights[2] |" in (out / "fit.md").read_text()
    assert rep["validation_starts_at_rest"] is False  # a sine from its zero crossing
    assert rep["validation_initial_states"].startswith("first input")
    # Refuses to overwrite; --plays auto picks 3 among 2 and 3.
    assert main(["fit", str(tmp_path / "d.csv"), "--plays", "3", "--out", str(out)]) == 2
    assert "already exists" in capsys.readouterr().err
    rc = main(
        [
            "fit",
            str(tmp_path / "d.csv"),
            "--plays",
            "auto",
            "--candidates",
            "2,3",
            "--out",
            str(out),
            "--force",
            "--quiet",
        ]
    )
    assert rc == 0
    rep = __import__("json").loads((out / "fit.json").read_text())
    assert rep["n_plays"] == 3 and rep["selection"]["candidates"] == [2, 3]
    # --fit-from: a transient before t = 0.2 s is left out of the fit and of its RMSE.
    yt = y.copy()
    yt[:40] += 3.0 * np.exp(-np.arange(40) / 8.0)
    write_record(tmp_path / "transient.csv", u, yt)
    rc = main(
        [
            "fit",
            str(tmp_path / "transient.csv"),
            "--plays",
            "3",
            "--fit-from",
            "0.2",
            "--out",
            str(out),
            "--force",
            "--quiet",
        ]
    )
    assert rc == 0
    rep = __import__("json").loads((out / "fit.json").read_text())
    assert rep["fit_from"] == 0.2 and rep["n_fitted_samples"] == T - 40
    assert rep["rmse"] < 1e-8
    np.testing.assert_allclose(rep["thresholds"], R_TRUE, atol=1e-6)


def test_cli_fit_bad_input(tmp_path, capsys):
    from piest_jax._cli import main

    u, y = record()
    (tmp_path / "bad.csv").write_text("t,u,y\n0,1,2\n0.1,x,3\n")
    out = str(tmp_path / "o")
    # --plays defaults to auto, so a bare `piest fit DATA.csv` reaches the data and names it.
    assert main(["fit", str(tmp_path / "bad.csv"), "--out", out]) == 2
    err = capsys.readouterr().err
    assert "bad.csv" in err and "row 3" in err and "not a number" in err
    write_record(tmp_path / "short.csv", u[:10], y[:10])
    assert main(["fit", str(tmp_path / "short.csv"), "--plays", "6", "--out", out]) == 2
    assert "parameters but only 10 samples" in capsys.readouterr().err
    write_record(tmp_path / "flat.csv", np.ones(20), y[:20])
    assert main(["fit", str(tmp_path / "flat.csv"), "--plays", "2", "--out", out]) == 2
    err = capsys.readouterr().err
    assert "flat.csv: the input u is constant (1): it excites no play" in err
    assert main(["fit", str(tmp_path / "short.csv"), "--candidates", "5,6", "--out", out]) == 2
    assert "10 samples are too few to choose among --candidates 5,6" in capsys.readouterr().err
    write_record(tmp_path / "d.csv", u, y)
    assert main(["fit", str(tmp_path / "d.csv"), "--fit-from", "99", "--out", out]) == 2
    assert "no sample at or after --fit-from 99 (the record ends at t = 1.995)" in (capsys.readouterr().err)
    assert main(["fit", str(tmp_path / "d.csv"), "--fit-from", "1.97", "--candidates", "3", "--out", out]) == 2
    assert "6 samples from --fit-from on are too few to choose" in capsys.readouterr().err
    for argv, needle in [
        (["--plays", "many"], "or 'auto'"),
        (["--candidates", "2,x"], "2,3,4"),
        (["--candidates", "2,2"], "repeated"),
    ]:
        with pytest.raises(SystemExit) as e:
            main(["fit", str(tmp_path / "flat.csv"), *argv, "--out", out])
        assert e.value.code == 2
        assert needle in capsys.readouterr().err


def test_solver_objects_are_accepted(clean):
    import optimistix as optx

    u, y, f = clean
    # The named default is this object: the same fit, bit for bit.
    same = pj.fit_pi(u, y, 3, key=jax.random.key(0), solver=optx.LevenbergMarquardt(rtol=1e-6, atol=1e-9))
    np.testing.assert_array_equal(np.asarray(same.thresholds), np.asarray(f.thresholds))
    np.testing.assert_array_equal(np.asarray(same.weights), np.asarray(f.weights))
    # Another solver, with its own tolerances, reaches the same optimum.
    dog = pj.fit_pi(u, y, 3, key=jax.random.key(0), solver=optx.Dogleg(rtol=1e-8, atol=1e-10))
    assert dog.result_name == "successful"
    np.testing.assert_allclose(dog.thresholds, R_TRUE, atol=1e-5)
    with pytest.raises(ValueError, match="the class Dogleg, not a solver: pass an instance"):
        pj.fit_pi(u, y, 3, solver=optx.Dogleg)


def test_a_long_record_is_chosen_on_its_first_stretch(noisy, monkeypatch):
    # Above SELECT_SAMPLES the candidates are fitted and scored on the stretch of that many
    # samples from the first used one; the chosen model is fitted on every sample.
    from piest_jax._identification import holdout

    u, y, _ = noisy
    used = np.ones(T)
    used[:30] = 0.0
    monkeypatch.setattr(holdout, "SELECT_SAMPLES", 250)
    assert holdout.selection_stretch(used) == 280
    sel = pj.select_plays(u, y, (2, 3), patience=None, n_starts=1, mask=used)
    assert sel.selection_samples == 280 and sel.n_plays == 3
    for n, score in zip(sel.candidates, sel.scores):
        split = holdout_mask(280, 0.3)
        f = pj.fit_pi(u[:280], y[:280], n, n_starts=1, mask=split * used[:280])
        test = (split == 0) & (used[:280] > 0)
        assert score == pytest.approx(np.sqrt(np.mean((np.asarray(f(u[:280]))[test] - y[:280][test]) ** 2)), rel=1e-6)
    whole = pj.fit_pi(u, y, 3, n_starts=1, mask=used)
    np.testing.assert_allclose(sel.fit.rmse, whole.rmse, rtol=1e-6)
    choice = pj.select_model(u, y, 1.0, (2, 3), (0,), n_starts=1, mask=used)
    assert choice.selection_samples == 280 and choice.n_plays == 3
    assert choice.scores == pytest.approx(sel.scores, rel=1e-6)
    np.testing.assert_allclose(choice.fit.rmse, whole.rmse, rtol=1e-6)
    # BIC scores whole-record fits.
    assert pj.select_plays(u, y, (2, 3), criterion="bic", n_starts=1).selection_samples == T


def test_quiet_fit_prints_only_the_paths(tmp_path, capsys):
    from piest_jax._cli import main

    t = np.linspace(0, 8, 600)
    u = 3 * np.sin(2 * np.pi * 0.5 * t)
    y = np.asarray(pj.PIOperator([0.0, 1.0], [1.0, 0.5], u[0])(u)) + 0.001 * np.random.default_rng(4).standard_normal(
        600
    )
    path = tmp_path / "d.csv"
    np.savetxt(path, np.column_stack([t, u, y]), delimiter=",", header="t,u,y", comments="")
    out = tmp_path / "o"
    assert main(["fit", str(path), "--plays", "2", "--model", "pi", "--out", str(out), "--quiet"]) == 0
    cap = capsys.readouterr()
    assert cap.err == "" and cap.out.split() == [str(out / n) for n in ("fit.json", "fit.md", "fit.png")]
