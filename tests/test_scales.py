"""Extreme scales: estimators and fits give finite results (in the user's units) for u and y from
1e-6 to 1e6, in float32 and float64; a 10⁶-sample record goes through loading, the PI operator
and one estimator without large memory overheads. (Heavier measurements, every estimator at every
scale and on the long record: experiments/reliability_scales.py.)"""

import json
import subprocess
import sys
import textwrap

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import reference as ref

import piest_jax as pj
from piest_jax._data.record import Record
from piest_jax._diagnosis import diagnose as _diagnose

SCALES = [1e-6, 1.0, 1e6]
PAIRS = [(su, sy) for su in SCALES for sy in SCALES]
R = np.array([0.0, 0.3, 0.6])
W = np.array([1.0, 3.0, 5.0])
DT = 1e-3


@pytest.fixture(scope="module")
def unit_problem():
    k = np.arange(1500)
    u = np.sin(2 * np.pi * 5 * k * DT) * (1 + 0.5 * np.sin(2 * np.pi * 1.3 * k * DT))
    H = ref.play(u, R)
    return H, H @ W


def _scaled(H, y, dtype):
    Hs = np.stack([H * su for su, _ in PAIRS])
    ys = np.stack([y * sy for _, sy in PAIRS])
    return jnp.asarray(Hs, dtype), jnp.asarray(ys, dtype)


def _all_finite(e):
    return all(bool(jnp.all(jnp.isfinite(a))) for a in jax.tree.leaves(e))


@eqx.filter_jit
def _forgetting(Hs, ys, P0s):
    return jax.vmap(lambda H, y, P0: pj.estimate(pj.ForgettingRLS(P0, 1.0), H, y))(Hs, ys, P0s)


@eqx.filter_jit
def _continuous(Hs, ys):
    return jax.vmap(lambda H, y: pj.estimate(pj.ContinuousRLS(1e6, DT), H, y))(Hs, ys)


@eqx.filter_jit
def _gradient(Hs, ys):
    return jax.vmap(lambda H, y: pj.estimate(pj.NormalisedGradient(1.0), H, y))(Hs, ys)


@pytest.mark.parametrize("dtype, rtol", [(jnp.float32, 2e-4), (jnp.float64, 1e-9)])
def test_least_squares_is_scale_equivariant(unit_problem, dtype, rtol):
    # With h -> a h, y -> b y and P0 -> P0 / a², discrete RLS gives exactly W -> (b / a) W: results
    # in the user's units do not depend on the units, down to rounding, in either precision.
    H, y = unit_problem
    Hs, ys = _scaled(H, y, dtype)
    P0s = jnp.asarray([1e8 / su**2 for su, _ in PAIRS], dtype)
    e = _forgetting(Hs, ys, P0s)
    assert _all_finite(e)
    assert e.weights.dtype == dtype
    w_user = np.asarray(e.weights[:, -1], np.float64) * np.array([[su / sy] for su, sy in PAIRS])
    np.testing.assert_allclose(w_user, np.broadcast_to(W, w_user.shape), rtol=rtol)


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
@pytest.mark.parametrize("run", [_continuous, _gradient], ids=["continuous_rls", "normalised_gradient"])
def test_normalised_estimators_stay_finite_at_any_scale(unit_problem, dtype, run):
    # The paper's normalisation m = 1 + h'h keeps every update bounded, whatever the units.
    H, y = unit_problem
    e = run(*_scaled(H, y, dtype))
    assert _all_finite(e)
    assert e.weights.dtype == dtype
    assert np.all(np.asarray(e.gain_min_eig) >= 0)


_ESTIMATORS = {
    "forgetting_rls": (pj.ForgettingRLS(1e6, 1.0), 1e-5),
    "continuous_rls": (pj.ContinuousRLS(1e6, DT), 2e-4),
    # the normalised gradient converges slowest: about 1e-2 relative after 1.5 s
    "normalised_gradient": (pj.NormalisedGradient(1.0), 2e-2),
}


@eqx.filter_jit
def _rescaled(est, Hs, ys, w0s):
    return jax.vmap(lambda H, y, w0: pj.estimate(est, H, y, w0, rescale=True))(Hs, ys, w0s)


@pytest.mark.parametrize("dtype, rtol", [(jnp.float32, 2e-6), (jnp.float64, 1e-12)])
@pytest.mark.parametrize("name", list(_ESTIMATORS))
def test_rescale_gives_every_estimator_the_same_answer_in_any_units(unit_problem, name, dtype, rtol):
    # estimate(..., rescale=True) divides H and y by their peaks and reports in the user's units:
    # the same record in units from 1e-6 to 1e6 gives the same weights (times sy / su), errors
    # (times sy) and gains (divided by su²), down to rounding, and the weights are the truth to
    # within the estimator's convergence after 1.5 s, in float32 as in float64.
    est, conv = _ESTIMATORS[name]
    H, y = unit_problem
    Hs, ys = _scaled(H, y, dtype)
    su = np.array([a for a, _ in PAIRS])[:, None]
    sy = np.array([b for _, b in PAIRS])[:, None]
    e = _rescaled(est, Hs, ys, jnp.zeros((len(PAIRS), 3), dtype))
    assert _all_finite(e) and e.weights.dtype == dtype
    unit = PAIRS.index((1.0, 1.0))
    w = np.asarray(e.weights[:, -1], np.float64) * su / sy
    np.testing.assert_allclose(w, np.broadcast_to(w[unit], w.shape), rtol=0, atol=rtol * W.max())
    np.testing.assert_allclose(w[unit], W, rtol=0, atol=conv * W.max())
    err = np.asarray(e.error, np.float64) / sy
    np.testing.assert_allclose(err, np.broadcast_to(err[unit], err.shape), rtol=0, atol=rtol * np.abs(y).max())
    tr = np.asarray(e.gain_trace, np.float64) * su**2
    np.testing.assert_allclose(tr, np.broadcast_to(tr[unit], tr.shape), rtol=10 * rtol)
    # Initial weights are in the user's units too: started at the truth, noise-free data keep
    # every estimator there.
    w0 = jnp.asarray(W[None, :] * sy / su, dtype)
    e0 = _rescaled(est, Hs, ys, w0)
    np.testing.assert_allclose(
        np.asarray(e0.weights, np.float64) * (su / sy)[:, :, None], np.broadcast_to(W, e0.weights.shape), rtol=10 * rtol
    )


def test_rescale_keeps_flat_data_finite():
    # An output that never moves and a regressor that is all zero keep unit scale, not 0 / 0.
    H = jnp.zeros((50, 2))
    e = pj.estimate(pj.ForgettingRLS(10.0), H, jnp.zeros(50), rescale=True)
    assert _all_finite(e)
    np.testing.assert_array_equal(np.asarray(e.weights), 0.0)
    np.testing.assert_allclose(np.asarray(e.gain_trace), 20.0)
    Hs = jnp.asarray(np.abs(np.sin(np.arange(100.0)))[:, None] * [1.0, 0.5])
    e = pj.estimate(pj.NormalisedGradient(1.0), Hs * 1e6, jnp.zeros(100), rescale=True)
    assert _all_finite(e)
    np.testing.assert_array_equal(np.asarray(e.weights), 0.0)


@pytest.mark.parametrize("dtype, rtol", [(jnp.float32, 1e-4), (jnp.float64, 1e-9)])
def test_continuous_rls_on_normalised_data_reports_user_units(unit_problem, dtype, rtol):
    # The recipe for data in any units: divide by the half ranges (in the working precision),
    # estimate, multiply the weights by y_half / u_half.
    H, y = unit_problem
    Hs, ys = _scaled(H, y, dtype)
    u_half = 0.5 * (jnp.max(Hs[:, :, 0], axis=1) - jnp.min(Hs[:, :, 0], axis=1))
    y_half = 0.5 * (jnp.max(ys, axis=1) - jnp.min(ys, axis=1))
    e = _continuous(Hs / u_half[:, None, None], ys / y_half[:, None])
    w = e.weights[:, -1] * (y_half / u_half)[:, None]
    w_user = np.asarray(w, np.float64) * np.array([[su / sy] for su, sy in PAIRS])
    # The same answer whatever the units (down to rounding), and it is the truth to within the
    # estimator's convergence after 1.5 s (about 5e-5 relative here).
    unit = w_user[PAIRS.index((1.0, 1.0))]
    np.testing.assert_allclose(w_user, np.broadcast_to(unit, w_user.shape), rtol=rtol)
    np.testing.assert_allclose(unit, W, rtol=2e-4)


def test_diagnosis_accepts_any_scale_and_refuses_flat_signals():
    t = 0.01 * np.arange(400)
    u = np.sin(2 * np.pi * t)
    y = u + 0.1 * np.cos(2 * np.pi * t)
    for su in (1e-9, 1e-6, 1.0, 1e6, 1e9):
        for sy in (1e-9, 1e9):
            rec = Record(t, su * u, sy * y, source="scaled")
            _diagnose.check_record(rec)
            sc = _diagnose.scaling_of(rec)
            assert all(np.isfinite(v) and v != 0 for v in (sc.u_half, sc.y_half, sc.rate_scale))
            assert sc.u_half == pytest.approx(0.5 * np.ptp(su * u), rel=1e-12)
            assert sc.y_half == pytest.approx(0.5 * np.ptp(sy * y), rel=1e-12)
    cases = [((t, np.full_like(u, 1e-9), y), "input u is constant"), ((t, u, np.full_like(y, 1e9)), "constant output")]
    for bad, match in cases:
        with pytest.raises(ValueError, match=match):
            _diagnose.check_record(Record(*bad, source="flat"))


def test_fit_in_float64_at_extreme_scales():
    # float32 is checked on the long record below (its own process); here the test process's
    # float64. The fit normalises internally and reports in the user's units.
    from piest_jax._identification.fit import fit_pi

    k = np.arange(400)
    uu = np.sin(2 * np.pi * k / 100) * (1 + 0.4 * np.sin(2 * np.pi * k / 430))
    yy = ref.pi(uu, [0.0, 0.3, 0.7], [1.0, 0.6, 0.4], x0=uu[0]) + 0.2
    for su, sy in [(1e-6, 1e6), (1e6, 1e-6)]:
        f = fit_pi(su * uu, sy * yy, 3, n_starts=2, max_steps=60, key=jax.random.key(0))
        assert f.weights.dtype == jnp.float64
        np.testing.assert_allclose(np.asarray(f.thresholds) / su, [0.0, 0.3, 0.7], atol=1e-6)
        np.testing.assert_allclose(np.asarray(f.weights) * su / sy, [1.0, 0.6, 0.4], atol=1e-6)
        assert float(f.offset) / sy == pytest.approx(0.2, abs=1e-6)
        assert float(f.rmse) / sy < 1e-6


_LONG_RECORD = textwrap.dedent(
    """
    import json, resource, sys
    import numpy as np
    import jax
    jax.config.update("jax_enable_x64", sys.argv[2] == "float64")
    import piest_jax as pj
    from piest_jax._data.record import load_record
    from piest_jax._identification.fit import fit_pi
    base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    rec = load_record(sys.argv[1])
    loaded = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    r = 1e6 * np.linspace(0.0, 0.9, 10)
    w = np.linspace(1.0, 0.1, 10)
    op = pj.PIOperator(r, w, initial_states=rec.u[0])
    y = np.asarray(op(rec.u))
    H = np.asarray(op.regressor(rec.u))
    # One estimator over the whole record (weights kept for every sample: 10⁶ x 10 values).
    e = pj.estimate(pj.NormalisedGradient(1.0), H, rec.y)
    finite = all(bool(np.all(np.isfinite(np.asarray(a)))) for a in (e.weights, e.error, e.gain_trace))
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    out = dict(n=rec.n_samples, u_ok=bool(np.array_equal(rec.u[:1000], rec.u[-1000:])),
               y_last=y[-1000:].tolist(), H_last=H[-1].tolist(), dtype=str(y.dtype),
               estimate_finite=finite, estimate_shape=list(e.weights.shape),
               estimate_dtype=str(e.weights.dtype), base_kb=base, loaded_kb=loaded, peak_kb=peak)
    # The fit in the working precision at extreme scales (one compilation).
    k = np.arange(400)
    uu = np.sin(2 * np.pi * k / 100) * (1 + 0.4 * np.sin(2 * np.pi * k / 430))
    yy = np.asarray(pj.PIOperator([0.0, 0.3, 0.7], [1.0, 0.6, 0.4], initial_states=uu[0])(uu)) + 0.2
    fits = []
    for su, sy in [(1e-6, 1e6), (1e6, 1e-6)]:
        f = fit_pi(su * uu, sy * yy, 3, n_starts=2, max_steps=60)
        fits.append(dict(thresholds=(np.asarray(f.thresholds, float) / su).tolist(),
                         weights=(np.asarray(f.weights, float) * su / sy).tolist(),
                         offset=float(f.offset) / sy, dtype=str(f.weights.dtype)))
    out["fits"] = fits
    print(json.dumps(out))
    """
)


@pytest.fixture(scope="module")
def long_csv(tmp_path_factory):
    """10⁶ rows of a 1000-sample period: u ~ 1e6, y ~ 1e-6, t = k·1e-4 written as `ke-4`."""
    p = tmp_path_factory.mktemp("long") / "million.csv"
    k = np.arange(1000)
    us = [repr(v) for v in (1e6 * np.sin(2 * np.pi * k / 1000)).tolist()]
    ys = [repr(v) for v in (1e-6 * np.cos(2 * np.pi * k / 1000)).tolist()]
    with open(p, "w") as f:
        f.write("t,u,y\n")
        for start in range(0, 1_000_000, 100_000):
            f.write("".join(f"{i}e-4,{us[i % 1000]},{ys[i % 1000]}\n" for i in range(start, start + 100_000)))
    return p, np.array([float(v) for v in us])


@pytest.mark.parametrize("precision", ["float32"])
def test_million_samples_and_fits_in_working_precision(long_csv, precision):
    path, u_period = long_csv
    proc = subprocess.run(
        [sys.executable, "-c", _LONG_RECORD, str(path), precision], capture_output=True, text=True, timeout=600
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert out["n"] == 1_000_000 and out["u_ok"] and out["dtype"] == precision
    assert out["estimate_finite"] and out["estimate_shape"] == [1_000_000, 10]
    assert out["estimate_dtype"] == precision
    # The operator's output is periodic after the first period: the last period of the long run
    # equals the second period of a reference run on two periods.
    r, w = 1e6 * np.linspace(0.0, 0.9, 10), np.linspace(1.0, 0.1, 10)
    two = np.concatenate([u_period, u_period])
    y_ref = ref.pi(two, r, w, x0=two[0])[1000:]
    tol = 1e-6 if precision == "float64" else 1e-5
    np.testing.assert_allclose(out["y_last"], y_ref, rtol=0, atol=tol * np.abs(y_ref).max())
    np.testing.assert_allclose(out["H_last"], ref.play(two, r, x0=two[0])[-1], rtol=0, atol=tol * 1e6)
    # Memory: the 60 MB file is held as 24 MB of float64 columns; loading it, running the operator
    # and one estimator needs a few times the file size on top of the interpreter, not gigabytes.
    grown_mb = (out["peak_kb"] - out["base_kb"]) / 1024
    assert grown_mb < 600, out
    for f in out["fits"]:
        assert f["dtype"] == precision
        np.testing.assert_allclose(f["thresholds"], [0.0, 0.3, 0.7], atol=1e-3)
        np.testing.assert_allclose(f["weights"], [1.0, 0.6, 0.4], atol=1e-3)
        assert f["offset"] == pytest.approx(0.2, abs=1e-3)
