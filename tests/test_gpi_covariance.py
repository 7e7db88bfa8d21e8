"""The generalized PI fit's covariance: its Jacobian against finite differences, its standard
errors against the spread of the estimates over noise draws, and the parameters a record that
never reaches saturation cannot determine."""

import json

import jax
import numpy as np
import pytest
from test_fit_gpi import record, truth

import piest_jax as pj
from piest_jax._identification import covariance as _cov
from piest_jax._identification import gpi_covariance

pytestmark = pytest.mark.long

jax.config.update("jax_enable_x64", True)


@pytest.mark.parametrize("states", [False, True], ids=["states_given", "states_fitted"])
def test_jacobian_matches_finite_differences(states):
    u = record(200)
    g = truth(u[0]).with_initial_states(np.array([u[0], u[0] - 0.2, u[0] + 0.5]))
    theta = np.asarray(gpi_covariance.flatten(g, states))
    x0 = np.asarray(g.pi.initial_states)
    pred, J = gpi_covariance.jacobian(theta, u, x0, 3, 2, states)
    # The model run from the parameters is the model itself.
    np.testing.assert_allclose(pred, g(u), rtol=1e-12, atol=1e-12)
    h = 1e-6
    for i in range(theta.size):
        d = np.zeros_like(theta)
        d[i] = h
        up = gpi_covariance.jacobian(theta + d, u, x0, 3, 2, states)[0]
        down = gpi_covariance.jacobian(theta - d, u, x0, 3, 2, states)[0]
        np.testing.assert_allclose(
            J[:, i],
            (np.asarray(up) - np.asarray(down)) / (2 * h),
            rtol=1e-5,
            atol=1e-6,
            err_msg=gpi_covariance.names(3, 2, states)[i],
        )


@pytest.mark.optimized
@pytest.mark.parametrize("method", _cov.METHODS)
def test_calibration_over_noise_draws(method):
    # 200 white-noise draws: the sample standard deviation of each estimate is known to about
    # 5 %, so the 0.8-1.25 band on (mean predicted std error) / (spread) is more than four of its
    # standard errors wide on either side for each of the 11 parameters.
    u = record()
    y0 = np.asarray(truth(u[0])(u))
    noise = 0.01 * np.random.default_rng(5).standard_normal((200, u.size))
    est, se = [], []
    for e in noise:
        f = pj.fit_gpi(u, y0 + e, 3, n_starts=1, covariance=method)
        assert f.result_name == "successful"
        est.append(np.asarray(f.parameter_values))
        se.append(np.asarray(f.std_errors))
    ratio = np.mean(se, axis=0) / np.std(est, axis=0, ddof=1)
    assert np.all((0.8 < ratio) & (ratio < 1.25)), dict(zip(f.parameter_names, ratio))
    assert f.covariance_method == method and f.determined


def test_a_record_that_never_saturates_leaves_the_output_function_undetermined():
    # Driven over a fifth of its range, the model's output function is nearly straight: its
    # amplitudes, centres and scales trade against each other and against the weights.
    u = 1.0 + 0.2 * (record() - 1.0)
    y = np.asarray(truth(u[0])(u)) + 1e-3 * np.random.default_rng(0).standard_normal(u.size)
    f = pj.fit_gpi(u, y, 3)
    assert not f.determined
    assert {"output.amplitudes[0]", "output.scales[1]"} <= set(f.undetermined_names)
    # The full range determines every parameter.
    u = record()
    y = np.asarray(truth(u[0])(u)) + 1e-3 * np.random.default_rng(0).standard_normal(u.size)
    assert pj.fit_gpi(u, y, 3).determined


def test_no_covariance_and_a_bad_name():
    u = record(200)
    y = np.asarray(truth(u[0])(u))
    f = pj.fit_gpi(u, y, 2, covariance=None)
    assert f.std_errors is None and f.undetermined_names == () and f.parameter_names == ()
    with pytest.raises(ValueError, match="unknown covariance 'sandwich'"):
        pj.fit_gpi(u, y, 2, covariance="sandwich")


def test_cli_fit_json_has_a_standard_error_for_every_parameter(tmp_path):
    u = record(300)
    y = np.asarray(truth(u[0])(u)) + 1e-3 * np.random.default_rng(1).standard_normal(u.size)
    data = tmp_path / "r.csv"
    data.write_text("t,u,y\n" + "\n".join(f"{i * 1e-3:.6f},{a:.17g},{b:.17g}" for i, (a, b) in enumerate(zip(u, y))))
    assert (
        pj.run_cli(["fit", str(data), "--model", "gpi", "--plays", "3", "--out", str(tmp_path / "o"), "--quiet"]) == 0
    )
    rep = json.loads((tmp_path / "o" / "fit.json").read_text())
    want = gpi_covariance.names(3, 2, False)
    assert tuple(rep["std_errors"]) == want
    assert all(v is not None and v > 0 for v in rep["std_errors"].values())
    assert rep["covariance"]["parameter_names"] == list(want) and rep["undetermined"] == []
    assert np.shape(rep["covariance"]["matrix"]) == (len(want), len(want))
    assert "± " in (tmp_path / "o" / "fit.md").read_text()
