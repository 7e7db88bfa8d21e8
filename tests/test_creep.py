"""The creep operator (a bank of first-order lags) and the composite model PI + creep + offset."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import piest_jax as pj
from piest_jax._models.creep import lag_states


def reference_lags(u, tau, dt, z0):
    """A plain NumPy loop: the exact zero-order-hold lag z[t] = a z[t-1] + (1 - a) u[t]."""
    a = np.exp(-dt / np.asarray(tau, float))
    z = np.broadcast_to(np.asarray(z0, float), a.shape).copy()
    out = np.empty((len(u), len(a)))
    for t, ut in enumerate(u):
        z = a * z + (1 - a) * ut
        out[t] = z
    return out


def _assert_weighted_sum(out, states, c):
    # A sum of terms of both signs rounds relative to its terms, not to the sum (which may be ~0).
    err = np.abs(np.asarray(out) - states @ c)
    np.testing.assert_array_less(err, 1e-12 * (np.abs(states) @ np.abs(c)))


def test_matches_reference(rng):
    u = np.cumsum(rng.standard_normal(300))
    tau, c, dt = np.array([0.02, 0.5, 7.0]), np.array([1.0, -0.4, 2.5]), 0.01
    cr = pj.Creep(tau, c, dt)
    np.testing.assert_allclose(cr.states(u), reference_lags(u, tau, dt, u[0]), rtol=1e-12)
    _assert_weighted_sum(cr(u), reference_lags(u, tau, dt, u[0]), c)
    z0 = np.array([1.0, -2.0, 3.0])
    cr0 = pj.Creep(tau, c, dt, initial_states=z0)
    _assert_weighted_sum(cr0(u), reference_lags(u, tau, dt, z0), c)
    np.testing.assert_allclose(cr0.final_states(u), reference_lags(u, tau, dt, z0)[-1])


def test_step_response_is_the_continuous_lag():
    # Exact discretisation: a step sampled every dt follows 1 - exp(-t/τ) at the samples.
    dt, tau = 0.1, 1.3
    u = np.ones(50)
    z = np.asarray(pj.Creep([tau], [1.0], dt, initial_states=0.0).states(u))[:, 0]
    t = dt * np.arange(1, 51)
    np.testing.assert_allclose(z, 1 - np.exp(-t / tau), rtol=1e-12)


def test_associative_equals_scan(rng):
    u = jnp.asarray(rng.standard_normal(257))
    a = jnp.asarray([0.1, 0.9, 0.999])
    z0 = jnp.asarray([0.3, -1.0, 2.0])
    np.testing.assert_allclose(lag_states(u, a, z0, method="associative"), lag_states(u, a, z0), rtol=1e-10, atol=1e-12)


def test_creep_associative_method_equals_scan(rng):
    u = jnp.asarray(rng.standard_normal(300))
    kw = dict(time_constants=[0.02, 0.5, 4.0], weights=[1.0, -2.0, 0.5], dt=0.01, initial_states=[0.1, 0.0, -0.3])
    scan, assoc = pj.Creep(**kw), pj.Creep(**kw, method="associative")
    np.testing.assert_allclose(assoc(u), scan(u), rtol=1e-10, atol=1e-12)
    # The method survives a restart from other initial states (the composite model's `at`).
    model = pj.HysteresisModel(pj.PIOperator([0.0, 0.3], [1.0, 0.5]), assoc, 0.0, 0.01)
    assert model.with_initial_states(creep_states=[0.0, 0.0, 0.0]).creep.method == "associative"
    with pytest.raises(ValueError, match="unknown lag method 'kernel'"):
        pj.Creep(**kw, method="kernel")


def test_vmap_equals_loop(rng):
    us = rng.standard_normal((4, 60))
    cr = pj.Creep([0.1, 1.0], [1.0, 2.0], 0.05)
    batched = jax.vmap(cr)(jnp.asarray(us))
    np.testing.assert_allclose(batched, np.stack([cr(u) for u in us]), rtol=1e-12)


@given(
    u=st.lists(st.floats(-1e3, 1e3), min_size=1, max_size=40),
    log_tau=st.lists(st.floats(-30.0, 30.0), min_size=1, max_size=4),
)
def test_stable_for_any_parameter(u, log_tau):
    # τ = exp(θ) > 0 for every θ, so 0 <= a <= 1 and every state stays in the hull of the input
    # and the initial state: no parameter value makes the recurrence grow.
    u = np.asarray(u)
    cr = pj.Creep(np.exp(log_tau), np.ones(len(log_tau)), 1.0)
    z = np.asarray(cr.states(u))
    assert np.all(np.isfinite(z))
    lo, hi = min(u.min(), u[0]), max(u.max(), u[0])
    assert np.all(z >= lo - 1e-9 * (1 + abs(lo))) and np.all(z <= hi + 1e-9 * (1 + abs(hi)))


def test_gradient_matches_finite_differences(rng):
    u = jnp.asarray(np.cumsum(rng.standard_normal(120)) * 0.1)

    def out(log_tau, c):
        return jnp.sum(pj.Creep(jnp.exp(log_tau), c, 0.1)(u) ** 2)

    lt, c = jnp.asarray([-0.5, 1.5]), jnp.asarray([0.7, -1.2])
    g = jax.grad(out)(lt, c)
    eps = 1e-6
    fd = [(out(lt.at[i].add(eps), c) - out(lt.at[i].add(-eps), c)) / (2 * eps) for i in range(2)]
    np.testing.assert_allclose(g, fd, rtol=1e-6)


@pytest.mark.parametrize("tau", [0.0, -1.0, np.inf, np.nan])
def test_bad_time_constant(tau):
    with pytest.raises(ValueError, match="time_constants. must be positive and finite"):
        pj.Creep([1.0, tau], [1.0, 1.0], 0.1)


def test_bad_dt():
    with pytest.raises(ValueError, match="`dt` must be a positive finite number"):
        pj.Creep([1.0], [1.0], 0.0)


def test_composite_is_the_sum(rng):
    u = np.cumsum(rng.standard_normal(200)) * 0.2
    r, w = np.array([0.0, 0.3, 0.8]), np.array([1.0, 0.5, 0.2])
    pi = pj.PIOperator(r, w, u[0])
    cr = pj.Creep([0.5, 5.0], [0.3, -0.1], 0.05)
    m = pj.HysteresisModel(pi, cr, 1.5)
    assert m.structure == "pi+creep" and m.n_lags == 2 and m.dt == 0.05
    np.testing.assert_allclose(m(u), np.asarray(pi(u)) + np.asarray(cr(u)) + 1.5, rtol=1e-12)
    plain = pj.HysteresisModel(pi, None, 1.5)
    assert plain.structure == "pi"
    np.testing.assert_allclose(plain(u), np.asarray(pi(u)) + 1.5)
    moved = m.with_initial_states(0.0, [1.0, 2.0], 0.0)
    ref = np.asarray(pj.PIOperator(r, w, 0.0)(u)) + reference_lags(u, [0.5, 5.0], 0.05, [1, 2]) @ [0.3, -0.1]
    np.testing.assert_allclose(moved(u), ref, rtol=1e-12)
    with pytest.raises(ValueError, match="differs from the model's dt"):
        pj.HysteresisModel(pi, cr, 0.0, dt=0.1)
