"""Prediction bands of the generalized PI and Preisach fits: the standard error against an
independent J (central differences; the reference play's relays), and coverage of fresh noise."""

import jax
import numpy as np
import pytest
from test_fit_gpi import record, truth
from test_preisach_covariance import K, M, dense_relays, signal

import piest_jax as pj
from piest_jax._identification import gpi_covariance
from piest_jax._identification.fit_preisach import triangle

jax.config.update("jax_enable_x64", True)


@pytest.fixture(scope="module")
def gpi_fit():
    u = record()
    y0 = np.asarray(truth(u[0])(u))
    return u, y0, pj.fit_gpi(u, y0 + 0.01 * np.random.default_rng(0).standard_normal(u.size), 3)


def test_gpi_std_error_equals_finite_difference_propagation(gpi_fit):
    u, _, f = gpi_fit
    v = 1.0 + 0.8 * (record(250, seed=3) - 1.0)
    band = pj.prediction_band(f, v)
    theta = np.asarray(gpi_covariance.flatten(f.model, False))
    x0 = np.asarray(f.model.pi.initial_states)

    def out(th):
        return np.asarray(gpi_covariance.jacobian(th, v, x0, 3, 2, False)[0])

    J = np.stack([(out(theta + h) - out(theta - h)) / 2e-6 for h in 1e-6 * np.eye(theta.size)], 1)
    want = np.sqrt(np.einsum("tp,pq,tq->t", J, np.asarray(f.covariance), J))
    np.testing.assert_allclose(band.std_error, want, rtol=1e-4, atol=1e-9)
    np.testing.assert_allclose(band.prediction, f.model(v), rtol=1e-12, atol=1e-12)


def test_gpi_measurement_band_covers_fresh_noise(gpi_fit):
    u, y0, f = gpi_fit
    fresh = y0 + 0.01 * np.random.default_rng(9).standard_normal((20, u.size))
    band = pj.prediction_band(f, u)
    cover = np.mean([band.coverage(y) for y in fresh])
    assert 0.90 < cover < 0.98


def test_preisach_std_error_equals_the_dense_computation():
    u = signal()
    y = np.tanh(u) + 0.02 * np.random.default_rng(4).standard_normal(u.size)
    f = pj.fit_preisach(u, y, n_widths=K, n_centres=M, smoothness=1e-3)
    v = signal(333, seed=5)
    band = pj.prediction_band(f, v, chunk=50)
    m = f.model
    B = dense_relays(v, np.asarray(m.half_widths), np.asarray(m.centres), np.asarray(m.blur), np.full(K, v[0]))[
        :, triangle(K, M).ravel()
    ]
    J = np.concatenate([B, np.ones((v.size, 1))], axis=1)
    want = np.sqrt(np.einsum("tp,pq,tq->t", J, np.asarray(f.covariance), J))
    np.testing.assert_allclose(band.std_error, want, rtol=1e-8, atol=1e-12)
    assert float(band.residual_std) == pytest.approx(float(f.residual_std))


def test_saturating_bands_refuse_creep_states_and_a_missing_covariance(gpi_fit):
    u, y0, f = gpi_fit
    with pytest.raises(ValueError, match="no creep or separate offset"):
        pj.prediction_band(f, u, offset=1.0)
    g = pj.fit_gpi(u, y0, 3, covariance=None)
    with pytest.raises(ValueError, match="the fit has no covariance"):
        pj.prediction_band(g, u)


@pytest.mark.parametrize(
    "model", [["--model", "gpi", "--plays", "3"], ["--model", "preisach", "--grid", "6,6"]], ids=["gpi", "preisach"]
)
def test_cli_reports_the_validation_band_coverage(tmp_path, model):
    import json

    u, v = record(400), record(300, seed=7)
    g = truth(u[0])
    rng = np.random.default_rng(2)
    for name, x in (("a.csv", u), ("b.csv", v)):
        y = np.asarray(g.with_initial_states(x[0])(x)) + 0.01 * rng.standard_normal(x.size)
        (tmp_path / name).write_text(
            "t,u,y\n" + "\n".join(f"{i * 1e-3:.6f},{a:.17g},{b:.17g}" for i, (a, b) in enumerate(zip(x, y)))
        )
    out = tmp_path / "o"
    assert (
        pj.run_cli(
            [
                "fit",
                str(tmp_path / "a.csv"),
                "--validate",
                str(tmp_path / "b.csv"),
                *model,
                "--out",
                str(out),
                "--quiet",
            ]
        )
        == 0
    )
    rep = json.loads((out / "fit.json").read_text())
    # The generating model is in both fits' class (the Preisach grid's nearly): the band covers
    # the validation record's fresh noise about as often as it says.
    assert 0.85 < rep["validation_band_coverage"] < 0.99
    assert "validation_band_coverage_ic" not in rep
    assert (out / "validation.png").stat().st_size > 0
