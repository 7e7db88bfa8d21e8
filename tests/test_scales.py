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

import piest_jax as pj
from piest_jax import _diagnose
from piest_jax._data import Record

import reference as ref

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
    for bad, match in [((t, np.full_like(u, 1e-9), y), "input u is constant"), ((t, u, np.full_like(y, 1e9)), "constant output")]:
        with pytest.raises(ValueError, match=match):
            _diagnose.check_record(Record(*bad, source="flat"))


_LONG_RECORD = textwrap.dedent(
    """
    import json, resource, sys
    import numpy as np
    import jax
    jax.config.update("jax_enable_x64", sys.argv[2] == "float64")
    import piest_jax as pj
    from piest_jax._data import load_record
    from piest_jax._fit import fit_pi
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
