"""Online estimators: references, stability over P0, dt and dtype, PE failure, errors."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import piest_jax as pj
from piest_jax._estimation.reproduce import CASES, DEFAULT_P0, THRESHOLDS

DT = 1e-3
T = np.arange(1001) * DT


def _case(name):
    case = CASES[name]
    u = case.input()
    op = pj.PIOperator(THRESHOLDS, case.weights)
    return np.asarray(op.regressor(u)), np.asarray(op(u)), np.asarray(case.weights)


FIG5 = _case("fig5")
FIG6 = _case("fig6")


def _ode_reference(H, y, p0, dt, substeps, normalisation="paper"):
    """The paper's eqs. 5-6, RK4 with the data held over each sample interval (NumPy)."""
    n = H.shape[1]
    w, P = np.zeros(n), p0 * np.eye(n)
    out = []
    for h, yk in zip(H, y):
        hh = h @ h
        m2 = (1 + hh) ** 2 if normalisation == "paper" else 1 + hh

        def f(w, P):
            return P @ h * (yk - h @ w) / m2, -P @ np.outer(h, h) @ P / m2

        d = dt / substeps
        for _ in range(substeps):
            k1 = f(w, P)
            k2 = f(w + d / 2 * k1[0], P + d / 2 * k1[1])
            k3 = f(w + d / 2 * k2[0], P + d / 2 * k2[1])
            k4 = f(w + d * k3[0], P + d * k3[1])
            w = w + d / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
            P = P + d / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
        out.append(w)
    return np.array(out)


@pytest.mark.parametrize("name", ["fig5", "fig6"])
def test_paper_figures_converge_noise_free(name):
    H, y, w_true = _case(name)
    res = pj.estimate(pj.ContinuousRLS(DEFAULT_P0, DT), H, y)
    final = np.asarray(res.weights[-1])
    assert np.all(np.abs(final - w_true) <= 1e-3 * np.abs(w_true))


@pytest.mark.parametrize("normalisation", ["paper", "standard"])
def test_exact_step_matches_paper_ode(normalisation):
    H, y, _ = FIG5
    H, y = H[:120], y[:120]
    # small P0 so that the ODE itself is non-stiff and RK4 converges
    ref = _ode_reference(H, y, 50.0, DT, 20, normalisation)
    got = pj.estimate(pj.ContinuousRLS(50.0, DT, normalisation=normalisation), H, y).weights
    np.testing.assert_allclose(got, ref, rtol=1e-8, atol=1e-10)


@pytest.mark.parametrize("P0", [1.0, 1e4, 1e8, 1e12, "matrix"])
@pytest.mark.parametrize("normalisation", ["paper", "standard"])
def test_sequential_scan_equals_information_form(P0, normalisation):
    H, y, _ = FIG6
    if P0 == "matrix":
        P0 = np.array([[2e6, 1e5, 0.0], [1e5, 5e5, -2e4], [0.0, -2e4, 1e6]])
    w0 = np.array([0.5, -1.0, 2.0])
    est = pj.ContinuousRLS(P0, DT, normalisation=normalisation)
    seq = np.asarray(pj.estimate(est, H, y, w0).weights)
    info = pj.information_form(H, y, P0, DT, normalisation=normalisation, initial_weights=w0)
    info = np.asarray(info)
    np.testing.assert_allclose(seq, info, rtol=1e-7, atol=1e-7 * np.abs(info).max())


GRID = np.array([(p, dt) for p in 10.0 ** np.arange(0, 13, 2) for dt in (1e-6, 1e-3, 1.0, 1e3)])


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
@pytest.mark.parametrize(
    "make",
    [
        lambda p, dt: pj.ContinuousRLS(p, dt),
        lambda p, dt: pj.ContinuousRLS(p, dt, normalisation="standard"),
        lambda p, dt: pj.ForgettingRLS(p, 0.98),
        lambda p, dt: pj.ForgettingRLS(p, 1.0, windup="none"),
    ],
    ids=["cont-paper", "cont-standard", "forget-0.98", "rls-1"],
)
def test_never_nan_or_inf_for_any_P0_and_dt(make, dtype):
    H, y, w_true = FIG5
    H, y, g = (jnp.asarray(a, dtype) for a in (H, y, GRID))
    res = jax.vmap(lambda p, dt: pj.estimate(make(p, dt), H, y))(g[:, 0], g[:, 1])
    assert res.weights.dtype == dtype
    for a in (res.weights, res.error, res.gain_trace, res.gain_max_eig):
        assert bool(jnp.all(jnp.isfinite(a))), dtype
    assert float(jnp.min(res.gain_min_eig)) >= 0.0
    # strong settings converge: P0 >= 1e8 at the paper's dt (the forgetting RLS ignores dt)
    strong = GRID[:, 0] * (GRID[:, 1] if isinstance(make(1.0, 1.0), pj.ContinuousRLS) else 1e-3)
    final = np.asarray(res.weights[:, -1], np.float64)[strong >= 1e5]
    tol = 1e-2 if dtype == jnp.float32 else 1e-4
    assert len(final) >= 8 and np.all(np.abs(final - w_true) <= tol * w_true), final


@pytest.mark.parametrize("normalisation", ["paper", "standard"])
def test_any_dt_and_P0_equals_closed_form(normalisation):
    H, y, w_true = FIG6
    H, y = H[:300], y[:300]

    def run(p, dt):
        return pj.estimate(pj.ContinuousRLS(p, dt, normalisation=normalisation), H, y).weights

    w = np.asarray(jax.vmap(run)(GRID[:, 0], GRID[:, 1]))
    for (p, dt), wk in zip(GRID, w):
        info = np.asarray(pj.information_form(H, y, p, dt, normalisation=normalisation))
        np.testing.assert_allclose(wk, info, rtol=1e-6, atol=1e-6 * np.abs(info).max())
        if p * dt >= 1e9:
            np.testing.assert_allclose(wk[-1], w_true, rtol=1e-4)


@settings(max_examples=20)
@given(
    st.floats(0.0, 12.0),
    st.floats(-6.0, 3.0),
    st.lists(st.floats(-10.0, 10.0), min_size=3, max_size=3),
)
def test_property_scan_equals_closed_form(log_p0, log_dt, w0):
    H, y, _ = FIG6
    H, y = H[:300], y[:300]
    p0, dt = 10.0**log_p0, 10.0**log_dt
    seq = np.asarray(pj.estimate(pj.ContinuousRLS(p0, dt), H, y, np.asarray(w0)).weights)
    info = np.asarray(pj.information_form(H, y, p0, dt, initial_weights=np.asarray(w0)))
    scale = max(np.abs(info).max(), 1.0)
    np.testing.assert_allclose(seq, info, rtol=1e-6, atol=1e-6 * scale)


def test_forgetting_rls_matches_numpy_loop():
    H, y, _ = FIG6
    rng = np.random.default_rng(1)
    y = y + 0.05 * rng.normal(size=y.shape)
    lam, p0 = 0.97, 100.0
    w, P, ref = np.zeros(3), p0 * np.eye(3), []
    for h, yk in zip(H, y):
        g = P @ h / (lam + h @ P @ h)
        w = w + g * (yk - h @ w)
        P = (P - np.outer(g, h @ P)) / lam
        ref.append(w)
    res = pj.estimate(pj.ForgettingRLS(p0, lam, windup="none"), H, y)
    np.testing.assert_allclose(res.weights, np.array(ref), rtol=1e-8, atol=1e-9)
    np.testing.assert_allclose(res.gain_trace[-1], np.trace(P), rtol=1e-8)


def test_normalised_gradient_matches_numpy_loop_and_converges():
    H, y, w_true = FIG5
    mu = 1.3
    w, ref = np.zeros(3), []
    for h, yk in zip(H, y):
        w = w + mu * h * (yk - h @ w) / (1 + h @ h)
        ref.append(w)
    res = pj.estimate(pj.NormalisedGradient(mu), H, y)
    np.testing.assert_allclose(res.weights, np.array(ref), rtol=1e-10, atol=1e-12)
    # slower than least squares, but converging under PE (5 s of the Fig. 5 input)
    t = np.arange(5001) * DT
    op = pj.PIOperator(THRESHOLDS, w_true)
    u = 10 * np.sin(2 * np.pi * 5 * t)
    long = pj.estimate(pj.NormalisedGradient(1.0), op.regressor(u), op(u))
    err = np.linalg.norm(np.asarray(long.weights) - w_true, axis=1)
    assert err[-1] < 0.1 * err[0]


def test_non_pe_input_stays_finite_and_windup_is_bounded():
    u = 2.0 * np.sin(2 * np.pi * 5 * T)
    op = pj.PIOperator(THRESHOLDS, (1.0, 3.0, 5.0))
    H, y = np.asarray(op.regressor(u)), np.asarray(op(u))
    assert abs(float(pj.pe_level(H, 200))) < 1e-12
    cont = pj.estimate(pj.ContinuousRLS(1e12, DT), H, y)
    assert bool(jnp.all(jnp.isfinite(cont.weights)))
    # the excited direction is learned, the unexcited gain stays at P0 (no growth)
    np.testing.assert_allclose(cont.weights[-1, 0], 1.0 + 3.0 * 0 + 5.0 * 0, rtol=1e-6)
    np.testing.assert_allclose(cont.gain_max_eig[-1], 1e12, rtol=1e-6)
    capped = pj.estimate(pj.ForgettingRLS(10.0, 0.95, windup="trace"), H, y)
    assert float(jnp.max(capped.gain_trace)) <= 30.0 * (1 + 1e-9)
    reset = pj.estimate(pj.ForgettingRLS(10.0, 0.95, windup="reset", max_trace=40.0), H, y)
    assert float(jnp.max(reset.gain_trace)) <= 40.0 * (1 + 1e-9)
    wound = pj.estimate(pj.ForgettingRLS(10.0, 0.95, windup="none"), H, y)
    assert float(wound.gain_trace[-1]) > 1e20  # wind-up without protection
    for r in (capped, reset):
        assert bool(jnp.all(jnp.isfinite(r.weights)))


def test_windup_protection_when_excitation_stops():
    # half a second of the Fig. 5 sine, then the input holds still: h is constant from sample 500
    u = 10 * np.sin(2 * np.pi * 5 * T)
    u[500:] = u[499]
    op = pj.PIOperator(THRESHOLDS, (1.0, 3.0, 5.0))
    H, y = np.asarray(op.regressor(u)), np.asarray(op(u))
    assert np.all(H[500:] == H[499])
    wound = pj.estimate(pj.ForgettingRLS(10.0, 0.95, windup="none"), H, y)
    # unprotected, P grows like λ^-k in the directions h no longer visits
    assert float(wound.gain_trace[-1]) > 1e8 * float(wound.gain_trace[499])
    capped = pj.estimate(pj.ForgettingRLS(10.0, 0.95, windup="trace"), H, y)
    tr = np.asarray(capped.gain_trace)
    assert tr.max() <= 30.0 * (1 + 1e-9)
    np.testing.assert_allclose(tr[-1], 30.0, rtol=1e-9)  # the cap is active, not merely unreached
    reset = pj.estimate(pj.ForgettingRLS(10.0, 0.95, windup="reset", max_trace=1e3), H, y)
    tr = np.asarray(reset.gain_trace)
    assert tr.max() <= 1e3
    # each time the trace passes the cap, P restarts from P0 (trace 30)
    restarts = np.nonzero(np.isclose(tr[500:], 30.0, rtol=1e-9))[0]
    assert len(restarts) >= 3
    for r in (capped, reset):
        w = np.asarray(r.weights)
        assert np.all(np.isfinite(w))
        # what was learned while the input excited is kept once it stops (noise-free data)
        np.testing.assert_allclose(w[499], [1.0, 3.0, 5.0], rtol=1e-8)
        np.testing.assert_allclose(w[-1], w[499], rtol=1e-8)


def test_vmap_over_P0_equals_loop():
    H, y, _ = FIG5
    ps = jnp.asarray([1e3, 1e6, 1e9])
    batched = jax.vmap(lambda p: pj.estimate(pj.ContinuousRLS(p, DT), H, y).weights[-1])(ps)
    loop = [np.asarray(pj.estimate(pj.ContinuousRLS(float(p), DT), H, y).weights[-1]) for p in ps]
    np.testing.assert_allclose(batched, np.array(loop), rtol=1e-10)


def test_bad_input_errors():
    H, y, _ = FIG5
    with pytest.raises(ValueError, match="not symmetric"):
        pj.ContinuousRLS(np.array([[1.0, 2.0], [0.0, 1.0]]), DT)
    with pytest.raises(ValueError, match="smallest eigenvalue"):
        pj.ContinuousRLS(np.diag([1.0, -1.0, 2.0]), DT)
    with pytest.raises(ValueError, match="must be positive definite"):
        pj.ForgettingRLS(-1.0, 0.9)
    with pytest.raises(ValueError, match="a positive scalar or a square matrix"):
        pj.ContinuousRLS(np.ones((2, 3)), DT)
    with pytest.raises(ValueError, match="`P0` contains NaN or inf"):
        pj.ContinuousRLS(np.diag([1.0, np.nan, 1.0]), DT)
    with pytest.raises(ValueError, match="`max_trace` must be positive"):
        pj.ForgettingRLS(1.0, 0.9, max_trace=0.0)
    with pytest.raises(ValueError, match=r"forgetting factor must be in \(0, 1\]"):
        pj.ForgettingRLS(1.0, 1.5)
    with pytest.raises(ValueError, match=r"forgetting factor must be in \(0, 1\]"):
        pj.ForgettingRLS(1.0, 0.0)
    with pytest.raises(ValueError, match=r"gain must be in \(0, 2\)"):
        pj.NormalisedGradient(2.0)
    with pytest.raises(ValueError, match="`dt` must be positive"):
        pj.ContinuousRLS(1.0, 0.0)
    with pytest.raises(ValueError, match="unknown normalisation"):
        pj.ContinuousRLS(1.0, DT, normalisation="other")
    with pytest.raises(ValueError, match="unknown windup"):
        pj.ForgettingRLS(1.0, windup="clip")
    bad = H.copy()
    bad[10, 1] = np.nan
    with pytest.raises(ValueError, match="`H` contains NaN or inf"):
        pj.estimate(pj.ContinuousRLS(1.0, DT), bad, y)
    with pytest.raises(ValueError, match="`y` contains NaN or inf"):
        pj.estimate(pj.ContinuousRLS(1.0, DT), H, np.where(np.arange(len(y)) == 3, np.inf, y))
    with pytest.raises(ValueError, match="thresholds and regressor do not match"):
        pj.estimate(pj.ContinuousRLS(np.eye(4), DT), H, y)
    with pytest.raises(ValueError, match="`initial_weights` has shape"):
        pj.estimate(pj.ContinuousRLS(1.0, DT), H, y, np.zeros(2))
    with pytest.raises(ValueError, match="`y` has 10 samples"):
        pj.estimate(pj.ContinuousRLS(1.0, DT), H, y[:10])
    # traced settings are checked at run time
    run = eqx.filter_jit(lambda lam: pj.estimate(pj.ForgettingRLS(1.0, lam), H[:5], y[:5]).weights)
    with pytest.raises(eqx.EquinoxRuntimeError, match="forgetting factor"):
        run(1.5).block_until_ready()
    run_p0 = eqx.filter_jit(lambda p: pj.estimate(pj.ContinuousRLS(p, DT), H[:5], y[:5]).weights)
    with pytest.raises(eqx.EquinoxRuntimeError, match="`P0` must be positive"):
        run_p0(jnp.asarray(-1.0)).block_until_ready()
    run_mu = eqx.filter_jit(lambda mu: pj.estimate(pj.NormalisedGradient(mu), H[:5], y[:5]).weights)
    with pytest.raises(eqx.EquinoxRuntimeError, match=r"gain must be in \(0, 2\)"):
        run_mu(jnp.asarray(2.5)).block_until_ready()
    run_h = eqx.filter_jit(lambda H: pj.estimate(pj.ContinuousRLS(1.0, DT), H, y[:5]).weights)
    with pytest.raises(eqx.EquinoxRuntimeError, match="`H` contains NaN or inf"):
        run_h(jnp.asarray(np.where(np.arange(5)[:, None] == 2, np.nan, H[:5]))).block_until_ready()
