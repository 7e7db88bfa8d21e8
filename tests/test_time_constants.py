"""Bounds on fitted creep time constants: reversal counts against a plain loop, the bounded
parameterisation's properties, and fits that keep the bounds."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import piest_jax as pj
from piest_jax._identification import time_constants as tc


def reference_reversals(u, fraction):
    """Reversals counted sample by sample: the state follows the input at a distance of at
    most half the gap (a plain play loop), and each change of its direction is a reversal."""
    u = [float(v) for v in u]
    half = 0.5 * fraction * (max(u) - min(u))
    if half == 0:
        return 0
    x, direction, count = u[0], 0, 0
    for v in u[1:]:
        new = max(v - half, min(v + half, x))
        if new != x:
            d = 1 if new > x else -1
            count += direction != 0 and d != direction
            direction, x = d, new
    return count


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(-5, 5, allow_nan=False), min_size=3, max_size=60), st.sampled_from([0.05, 0.1, 0.3]))
def test_reversals_match_a_plain_loop(values, fraction):
    u = np.asarray(values)
    assert tc.reversals(u, fraction) == reference_reversals(u, fraction)


def test_reversals_of_a_sine_and_its_floor():
    dt, f, cycles = 1e-3, 2.0, 7
    t = np.arange(int(cycles / f / dt)) * dt
    u = np.sin(2 * np.pi * f * t + 0.3)
    # Every half cycle reverses once: 2 per cycle, give or take the ends.
    assert abs(tc.reversals(u) - 2 * cycles) <= 1
    n = tc.reversals(u)
    expected = tc.FLOOR_OMEGA_TAU / (np.pi * n / u.size) * dt
    np.testing.assert_allclose(pj.shortest_time_constant(u, dt), expected)
    # About a quarter of 1/ω at the sine's own frequency.
    np.testing.assert_allclose(pj.shortest_time_constant(u, dt), 0.25 / (2 * np.pi * f), rtol=0.1)
    # Constant and monotone inputs: the sample floor, and one reversal over the record.
    assert pj.shortest_time_constant(np.ones(50), dt) == tc.MIN_SAMPLES * dt
    ramp = np.linspace(0, 1, 4000)
    np.testing.assert_allclose(pj.shortest_time_constant(ramp, dt), 0.25 * 4000 / np.pi * dt)


@settings(max_examples=50, deadline=None)
@given(st.lists(st.floats(-4, 4, allow_nan=False), min_size=1, max_size=5), st.floats(1.0, 1e3))
def test_any_parameters_give_ordered_bounded_time_constants(theta, shortest):
    base = tc.lag_base(len(theta), shortest)
    log_tau = np.asarray(tc.lag_log_tau(jnp.asarray(theta, jnp.float64), base))
    assert log_tau[0] >= np.log(shortest) - 1e-12
    assert np.all(np.diff(log_tau) >= np.log(tc.LAG_RATIO) - 1e-12)


@settings(max_examples=50, deadline=None)
@given(st.lists(st.floats(0.01, 3.0), min_size=1, max_size=4), st.floats(1.0, 100.0))
def test_parameters_round_trip_inside_the_bounds(gaps, shortest):
    base = tc.lag_base(len(gaps), shortest)
    log_tau = base + np.cumsum(gaps)
    back = np.asarray(tc.lag_log_tau(tc.lag_theta(jnp.asarray(log_tau), base), base))
    np.testing.assert_allclose(back, log_tau, rtol=1e-12, atol=1e-12)


def test_starts_outside_the_bounds_begin_on_them():
    base = tc.lag_base(3, 10.0)
    # Below the floor, and two closer than the ratio allows.
    start = jnp.log(jnp.asarray([2.0, 50.0, 60.0]))
    got = np.exp(np.asarray(tc.lag_log_tau(tc.lag_theta(start, base), base)))
    assert got[0] == pytest.approx(10.0, rel=2e-3)
    assert got[1] == pytest.approx(50.0, rel=2e-3)
    assert got[2] == pytest.approx(got[1] * tc.LAG_RATIO, rel=2e-3)


def test_fit_keeps_the_bounds_and_names_bad_ones():
    dt, T = 0.01, 600
    t = dt * np.arange(T)
    u = 1.0 + np.sin(2 * np.pi * 0.5 * t)
    # A lag far faster than the input: the fit may not follow it below the floor.
    y = np.asarray(
        pj.HysteresisModel(pj.PIOperator([0.0, 0.4], [1.0, 0.5], u[0]), pj.Creep([0.02], [0.3], dt), 0.1, dt)(u)
    )
    floor = pj.shortest_time_constant(u, dt)
    f = pj.fit_pi(u, y, 2, n_lags=2, dt=dt, key=jax.random.key(0))
    tau = np.asarray(f.creep.time_constants)
    assert tau[0] >= floor * (1 - 1e-9) and tau[1] >= tau[0] * tc.LAG_RATIO * (1 - 1e-9)
    g = pj.fit_pi(u, y, 2, n_lags=1, dt=dt, min_time_constant=0.5, covariance=None)
    assert float(g.creep.time_constants[0]) >= 0.5 * (1 - 1e-9)
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(ValueError, match="min_time_constant"):
            pj.fit_pi(u, y, 2, n_lags=1, dt=dt, min_time_constant=bad)
