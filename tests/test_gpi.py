"""The generalized PI model: a NumPy reference, finite differences, and its properties."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import reference
from hypothesis import given
from hypothesis import strategies as st

import piest_jax as pj


def numpy_gpi(u, r, w, x0, a, c, s, offset):
    """y_t = offset + Σ_k a_k tanh((Σ_j w_j x_j(t) - c_k)/s_k), plays by the NumPy loop."""
    v = reference.pi(u, r, w, x0)
    out = np.empty(len(u))
    for t in range(len(u)):
        out[t] = offset + sum(a[k] * np.tanh((v[t] - c[k]) / s[k]) for k in range(len(a)))
    return out


def model(r=(0.0, 0.3, 0.7), w=(1.0, 0.6, 0.4), x0=0.0, a=(0.8, 0.5), c=(-0.1, 0.4), s=(0.9, 2.0), offset=0.2):
    return pj.GeneralizedPI(pj.PIOperator(np.array(r), np.array(w), x0), np.array(a), np.array(c), np.array(s), offset)


def wave(T=300, amp=2.0):
    t = np.linspace(0.0, 1.0, T)
    return amp * np.sin(2 * np.pi * 3 * t) * (0.3 + 0.7 * t)


def test_equals_numpy_reference():
    m = model(x0=np.array([0.1, -0.2, 0.3]))
    u = wave()
    ref = numpy_gpi(u, [0.0, 0.3, 0.7], [1.0, 0.6, 0.4], [0.1, -0.2, 0.3], [0.8, 0.5], [-0.1, 0.4], [0.9, 2.0], 0.2)
    np.testing.assert_allclose(np.asarray(m(u)), ref, rtol=0, atol=1e-12)


def test_vmap_equals_loop(rng):
    m = model()
    us = rng.normal(size=(4, 80)).cumsum(axis=1) * 0.2
    batched = np.asarray(jax.vmap(m)(jnp.asarray(us)))
    for k in range(4):
        np.testing.assert_allclose(batched[k], np.asarray(m(us[k])), rtol=0, atol=1e-14)


def test_gradient_matches_finite_differences():
    # No ties between a play's state and its bounds (a kink): u_0 and the states apart.
    u = jnp.asarray(wave(120) + 0.05)
    m = model(x0=np.array([0.1, -0.2, 0.3]))
    y = jnp.asarray(
        numpy_gpi(np.asarray(u) * 0.9, [0.0, 0.25, 0.8], [0.9, 0.5, 0.5], 0.0, [0.7, 0.6], [0.0, 0.3], [1.0, 1.5], 0.1)
    )

    def loss(m):
        return jnp.mean((m(u) - y) ** 2)

    grads = eqx.filter_grad(loss)(m)
    leaves, treedef = jax.tree.flatten(eqx.filter(m, eqx.is_inexact_array))
    g_leaves = jax.tree.leaves(eqx.filter(grads, eqx.is_inexact_array))
    h = 1e-6
    checked = 0
    for i, leaf in enumerate(leaves):
        if leaf is None:
            continue
        for j in range(leaf.size):

            def shifted(d, i=i, j=j):
                new = list(leaves)
                new[i] = leaf.ravel().at[j].add(d).reshape(leaf.shape)
                return eqx.combine(jax.tree.unflatten(treedef, new), m)

            if i == 0 and j == 0:
                continue  # r_1 = 0 lies on the boundary of r >= 0
            fd = (loss(shifted(h)) - loss(shifted(-h))) / (2 * h)
            np.testing.assert_allclose(float(g_leaves[i].ravel()[j]), float(fd), rtol=1e-5, atol=1e-9)
            checked += 1
    # thresholds (2 free), weights 3, initial states 3, log a 2, c 2, log s 2, offset 1
    assert checked == 15


params = st.tuples(
    st.lists(st.floats(0.05, 3.0), min_size=1, max_size=3),
    st.floats(-1.0, 1.0),
    st.floats(0.3, 3.0),
    st.integers(0, 2**31 - 1),
)


def random_model(p):
    amps, spread, scale, seed = p
    rng = np.random.default_rng(seed)
    k = len(amps)
    r = np.concatenate([[0.0], np.cumsum(rng.uniform(0.05, 0.4, 3))])
    w = rng.uniform(0.1, 1.0, 4)
    c = spread * rng.uniform(-1, 1, k)
    s = scale * rng.uniform(0.5, 2.0, k)
    return pj.GeneralizedPI(pj.PIOperator(r, w), np.array(amps), c, s, rng.normal()), rng


@given(params)
def test_output_function_strictly_increasing(p):
    m, _ = random_model(p)
    c, s = np.asarray(m.centres), np.asarray(m.scales)
    # Strictly where some term is not flat to float64's resolution, non-decreasing everywhere.
    v = jnp.linspace(c.min() - 5 * s.max(), c.max() + 5 * s.max(), 400)
    assert np.all(np.diff(np.asarray(m.output_function(v))) > 0)
    assert np.all(np.diff(np.asarray(m.output_function(jnp.linspace(-1e6, 1e6, 2001)))) >= 0)


# Compiled once per term count (the traced path: checks by `eqx.error_if`).
_roundtrip = eqx.filter_jit(lambda m, u: m.inverse(m(u)))


@given(params)
def test_inverse_of_forward_is_identity(p):
    m, rng = random_model(p)
    # Inputs where g is not flat to float64's resolution: the PI output within a few scales.
    u = np.concatenate([[0.0], np.cumsum(rng.normal(0.0, 0.1, 150))])
    u = u / max(np.max(np.abs(u)), 1e-9) * float(np.min(m.scales)) / float(jnp.sum(m.pi.weights))
    np.testing.assert_allclose(np.asarray(_roundtrip(m, jnp.asarray(u))), u, rtol=0, atol=1e-9)


@given(params, st.floats(1.0, 1e8))
def test_output_bounded_for_any_input(p, amplitude):
    m, _ = random_model(p)
    y = np.asarray(m(wave(200, amplitude)))
    lo, hi = (float(v) for v in m.output_range())
    assert np.all(y >= lo) and np.all(y <= hi)


def test_one_term_inverse_is_closed_form():
    m = model(a=(1.3,), c=(0.2,), s=(0.7,), offset=-0.4)
    y = jnp.linspace(-1.6, 0.8, 31)
    v = 0.2 + 0.7 * np.arctanh((np.asarray(y) + 0.4) / 1.3)
    np.testing.assert_allclose(np.asarray(m.output_inverse(y)), v, rtol=0, atol=1e-13)


def test_normalised_is_the_same_model():
    m = model(x0=np.array([0.1, 0.0, -0.1]))
    n = m.normalised()
    u = wave()
    np.testing.assert_allclose(float(n.scales[0]), 1.0)
    np.testing.assert_allclose(np.asarray(n(u)), np.asarray(m(u)), rtol=0, atol=1e-13)


def test_with_initial_states():
    m = model()
    u = wave()
    x = m.pi.final_states(u)
    v = wave(50) + u[-1]
    np.testing.assert_allclose(
        np.asarray(m.with_initial_states(x)(v)), np.asarray(m(np.concatenate([u, v])))[len(u) :], atol=1e-13
    )


def test_bad_parameters_are_refused():
    pi = pj.PIOperator(np.array([0.0, 0.5]), np.array([1.0, 0.5]))
    with pytest.raises(ValueError, match="`amplitudes` must be positive"):
        pj.GeneralizedPI(pi, [1.0, -0.1], [0.0, 0.0], [1.0, 1.0])
    with pytest.raises(ValueError, match="`scales` must be positive"):
        pj.GeneralizedPI(pi, [1.0], [0.0], [0.0])
    with pytest.raises(ValueError, match="`centres` must have 2 entries"):
        pj.GeneralizedPI(pi, [1.0, 1.0], [0.0], [1.0, 1.0])
    with pytest.raises(ValueError, match="`pi` must be a PIOperator"):
        pj.GeneralizedPI("pi", [1.0], [0.0], [1.0])


def test_unreachable_target_is_refused():
    m = model()
    hi = float(m.output_range()[1])
    with pytest.raises(ValueError, match="outside the range the model saturates at"):
        m.inverse(jnp.array([0.0, hi + 0.1]))
    with pytest.raises(Exception, match="outside the model's range"):
        jax.jit(lambda y: m.inverse(y))(jnp.array([0.0, hi]))


def test_not_invertible_pi_is_refused():
    m = pj.GeneralizedPI(pj.PIOperator(np.array([0.0, 0.5]), np.array([1.0, -1.5])), [1.0], [0.0], [1.0])
    with pytest.raises(ValueError, match="not invertible"):
        m.inverse(jnp.array([0.0, 0.1]))
