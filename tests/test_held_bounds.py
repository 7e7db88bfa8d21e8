"""Creep lags with free-sign weights, and lags the fit leaves on their bounds: held there by the
covariance rather than called undetermined."""

import jax
import numpy as np
import pytest
from test_creep import reference_lags
from test_fit import reference_pi
from test_fit_creep import DT, R, W, signal

import piest_jax as pj
from piest_jax._identification import covariance as _cov
from piest_jax._identification.time_constants import LAG_RATIO

NAMES = (
    "weights[0]",
    "offset",
    "creep.time_constants[0]",
    "creep.time_constants[1]",
    "creep.time_constants[2]",
    "creep.weights[0]",
)


@pytest.mark.parametrize(
    "gaps,held",
    [
        ([1.0, 1.0, 1.0], []),
        ([0.0, 1.0, 1.0], [0]),
        ([1.0, 1e-4, 0.0], [1, 2]),
        ([0.0, 0.0, 1.0], [0, 1]),
    ],
)
def test_on_bounds_maps_the_free_parameters(gaps, held):
    T, is_held = _cov.on_bounds(NAMES, np.asarray(gaps))
    where = {k: NAMES.index(f"creep.time_constants[{k}]") for k in range(3)}
    assert sorted(k for k in range(3) if is_held[where[k]]) == held
    assert T.shape == (len(NAMES), len(NAMES) - len(held))
    # A random change of the free parameters moves every parameter as the bounds say: the
    # fastest held lag not at all, a held lag above it by sqrt(10) times the lag below.
    free = np.random.default_rng(0).normal(size=T.shape[1])
    d = T @ free
    for k in held:
        want = 0.0 if k == 0 else LAG_RATIO * d[where[k - 1]]
        assert d[where[k]] == pytest.approx(want)
    np.testing.assert_array_equal(d[~is_held], free)


def test_a_lag_pushed_onto_the_floor_is_held_and_the_fit_determined():
    # A plant whose lag is five times faster than the fastest one the fit allows: the fitted lag
    # goes to the floor, where the constraint (not the record) sets its time constant; its
    # weight and the plays' are then determined, and the time constant is reported as held.
    u = signal(1200)
    floor = pj.shortest_time_constant(u, DT)
    y = (
        reference_pi(u, R, W, u[0])
        + 0.8 * reference_lags(u, np.array([floor / 5]), DT, u[0])[:, 0]
        + 0.002 * np.random.default_rng(0).standard_normal(u.size)
    )
    f = pj.fit_pi(u, y, 3, n_lags=1, dt=DT, key=jax.random.key(0))
    assert f.creep.time_constants[0] == pytest.approx(floor, rel=2e-3)
    assert f.held_names == ("creep.time_constants[0]",)
    i = f.parameter_names.index("creep.time_constants[0]")
    assert float(f.std_errors[i]) == 0.0
    assert f.determined, f.undetermined_names
    # Held parameters add nothing to the covariance: its row and column are 0.
    np.testing.assert_array_equal(np.asarray(f.covariance)[i], 0.0)


def test_a_relaxing_creep_gets_a_negative_weight_and_is_inverted():
    # After a change the output relaxes back (a negative lag weight): with signed weights the
    # fit finds the sign and positive play weights, and the composite model's inverse tracks
    # to rounding (its steady gain w_1 + c stays positive).
    u = signal(1000)
    tau, c = np.array([0.6]), np.array([-0.4])
    y = reference_pi(u, R, W, u[0]) + reference_lags(u, tau, DT, u[0]) @ c + 0.1
    f = pj.fit_pi(u, y, 3, n_lags=1, dt=DT, positive_weights=False, key=jax.random.key(0))
    np.testing.assert_allclose(f.creep.weights, c, rtol=1e-3)
    np.testing.assert_allclose(f.creep.time_constants, tau, rtol=1e-3)
    assert np.all(np.asarray(f.weights) > 0)
    target = np.asarray(f.model()(u))
    np.testing.assert_allclose(f.model()(pj.feedforward(f, target)), target, atol=1e-8)
