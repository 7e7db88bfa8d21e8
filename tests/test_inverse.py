"""The analytic inverse PI operator: closed forms, round trips, a bisection reference, errors."""

import hypothesis.extra.numpy as hnp
import hypothesis.strategies as st
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import reference as ref
from hypothesis import given, settings

import piest_jax as pj

T = 25
N = 4


def _operator_params(seed, n=N):
    """r with r_1 = 0, weights whose running sums stay in [0.1, 3] (some weights negative), and
    states some input history reaches."""
    rng = np.random.default_rng(seed)
    r = np.r_[0.0, np.cumsum(rng.uniform(0.1, 2.0, size=n - 1))]
    W = rng.uniform(0.1, 3.0, size=n)
    w = np.diff(W, prepend=0.0)
    x0 = ref.reachable_states(r, rng)
    return r, w, x0


@jax.jit
def _round_trips(r, w, x0, v):
    op = pj.PIOperator(r, w, x0)
    inv = pj.inverse(op)
    return op(inv(v)), inv(op(v)), inv(v)


@jax.jit
def _double_inverse(r, w, x0):
    back = pj.inverse(pj.inverse(pj.PIOperator(r, w, x0)))
    return back.thresholds, back.weights, back.initial_states


values = hnp.arrays(np.float64, T, elements=st.floats(-40, 40, allow_subnormal=False))
seeds = st.integers(0, 2**31 - 1)


@settings(max_examples=40)
@given(seeds, values)
def test_forward_of_inverse_and_inverse_of_forward_are_identity(seed, v):
    r, w, x0 = _operator_params(seed)
    fwd_inv, inv_fwd, _ = _round_trips(r, w, x0, v)
    np.testing.assert_allclose(fwd_inv, v, rtol=0, atol=1e-9)
    np.testing.assert_allclose(inv_fwd, v, rtol=0, atol=1e-9)


@settings(max_examples=20)
@given(seeds)
def test_inverse_of_inverse_is_the_operator(seed):
    r, w, x0 = _operator_params(seed)
    rb, wb, xb = _double_inverse(r, w, x0)
    np.testing.assert_allclose(rb, r, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(wb, w, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(xb, x0, rtol=1e-12, atol=1e-12)


def test_inverse_matches_bisection_reference():
    for seed in range(4):
        r, w, x0 = _operator_params(seed)
        v = 8.0 * np.sin(np.linspace(0, 9, T)) + np.random.default_rng(seed).normal(size=T)
        _, _, u = _round_trips(r, w, x0, v)
        np.testing.assert_allclose(u, ref.pi_inverse(v, r, w, x0), rtol=0, atol=1e-9)


def test_closed_form_values():
    # r = (0, 1, 2), w = (1, 1, 1): W = (1, 2, 3); r'_i = Σ_{j<=i} w_j (r_i - r_j) = (0, 1, 3);
    # w' = (1/w_1, -w_2/(W_2 W_1), -w_3/(W_3 W_2)) = (1, -1/2, -1/6);
    # x'_i = W_i x_i + Σ_{j>i} w_j x_j with x = (0.5, 0.2, 0) gives (0.7, 0.4, 0).
    op = pj.PIOperator(jnp.array([0.0, 1.0, 2.0]), jnp.ones(3), jnp.array([0.5, 0.2, 0.0]))
    inv = op.inverse()
    np.testing.assert_allclose(inv.thresholds, [0.0, 1.0, 3.0], rtol=0, atol=1e-15)
    np.testing.assert_allclose(inv.weights, [1.0, -0.5, -1.0 / 6.0], rtol=0, atol=1e-15)
    np.testing.assert_allclose(inv.initial_states, [0.7, 0.4, 0.0], rtol=0, atol=1e-15)
    # The inverse loading curve from rest: slopes 1, 1/2, 1/3 with corners at y = 1 and y = 3.
    relaxed = pj.PIOperator(jnp.array([0.0, 1.0, 2.0]), jnp.ones(3)).inverse()
    y = jnp.array([0.5, 1.0, 2.0, 3.0, 6.0])
    np.testing.assert_allclose(relaxed(y), [0.5, 1.0, 1.5, 2.0, 3.0], rtol=0, atol=1e-14)


def test_single_play_inverse_is_division():
    op = pj.PIOperator(0.0, jnp.array([4.0]), 2.0)
    inv = pj.inverse(op)
    assert inv.n_plays == 1
    np.testing.assert_allclose(inv.weights, [0.25], rtol=0, atol=0)
    np.testing.assert_allclose(inv.initial_states, [8.0], rtol=0, atol=0)
    np.testing.assert_allclose(inv(jnp.array([1.0, -2.0])), [0.25, -0.5], rtol=0, atol=1e-15)


def test_inverse_keeps_the_method():
    op = pj.PIOperator(jnp.array([0.0, 1.0]), jnp.ones(2), method="associative")
    assert pj.inverse(op).method == "associative"


def test_errors():
    with pytest.raises(ValueError, match=r"needs r_1 = 0 .* smallest threshold is 0\.5"):
        pj.inverse(pj.PIOperator(jnp.array([0.5, 1.0]), jnp.ones(2)))
    with pytest.raises(ValueError, match=r"cumulative weights .* at i = 2 they are -0\.5"):
        pj.inverse(pj.PIOperator(jnp.array([0.0, 1.0, 2.0]), jnp.array([1.0, -1.5, 2.0])))
    with pytest.raises(ValueError, match=r"at i = 1 they are 0"):
        pj.inverse(pj.PIOperator(jnp.array([0.0, 1.0]), jnp.array([0.0, 1.0])))
    with pytest.raises(ValueError, match=r"cannot be reached by any input history.*\|x_3 - x_2\|"):
        pj.inverse(pj.PIOperator(jnp.array([0.0, 1.0, 2.0]), jnp.ones(3), jnp.array([0.0, 0.5, 2.0])))


@pytest.mark.parametrize(
    "r, w, x0, match",
    [
        ([0.5, 1.0, 2.0], [1.0, 1.0, 1.0], [0.0, 0.0, 0.0], "need r_1 = 0"),
        ([0.0, 1.0, 2.0], [1.0, -1.5, 2.0], [0.0, 0.0, 0.0], "cumulative weights > 0"),
        ([0.0, 1.0, 2.0], [1.0, 1.0, 1.0], [0.0, 0.5, 2.0], "initial states are not admissible"),
    ],
)
def test_errors_under_jit(r, w, x0, match):
    args = (jnp.asarray(r), jnp.asarray(w), jnp.asarray(x0))
    with pytest.raises(RuntimeError, match=match):
        jax.block_until_ready(_double_inverse(*args))
