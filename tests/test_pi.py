"""The PI operator against a NumPy loop, fused output against the regressor, vmap, validation."""

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import reference as ref

import piest_jax as pj

T = 30
N = 5


def _case(rng, t=T, n=N):
    u = rng.normal(0.0, 2.0, size=t).cumsum()
    r = np.r_[0.0, np.sort(rng.uniform(0.05, 4.0, size=n - 1))]
    w = rng.normal(0.5, 1.0, size=n)
    x0 = rng.normal(0.0, 3.0, size=n)
    return u, r, w, x0


@functools.partial(jax.jit, static_argnames="method")
def _run(r, w, x0, u, method="scan"):
    op = pj.PIOperator(r, w, x0, method=method)
    return op(u), op.regressor(u), op.final_states(u)


@pytest.mark.parametrize("method", ["scan", "associative"])
def test_matches_numpy_loop(rng, method):
    for _ in range(5):
        u, r, w, x0 = _case(rng)
        y, H, xT = _run(r, w, x0, u, method)
        np.testing.assert_allclose(y, ref.pi(u, r, w, x0), rtol=0, atol=1e-12)
        np.testing.assert_allclose(H, ref.play(u, r, x0), rtol=0, atol=1e-12)
        np.testing.assert_array_equal(np.asarray(xT), np.asarray(H)[-1])


def test_fused_output_equals_regressor_times_weights(rng):
    for _ in range(5):
        u, r, w, x0 = _case(rng)
        y, H, _ = _run(r, w, x0, u)
        # Same products, possibly summed in another order: equal up to a few ulps.
        np.testing.assert_allclose(y, np.asarray(H) @ w, rtol=1e-14, atol=1e-12)


def test_scan_and_associative_regressors_bit_identical(rng):
    u, r, w, x0 = _case(rng)
    _, H1, _ = _run(r, w, x0, u, "scan")
    _, H2, _ = _run(r, w, x0, u, "associative")
    np.testing.assert_array_equal(np.asarray(H1), np.asarray(H2))


def test_scalar_initial_state_broadcasts_and_default_is_relaxed(rng):
    u, r, w, _ = _case(rng)
    op = pj.PIOperator(r, w, 0.7)
    assert op.initial_states.shape == (N,)
    np.testing.assert_allclose(op(u), ref.pi(u, r, w, 0.7), rtol=0, atol=1e-12)
    relaxed = pj.PIOperator(r, w)
    np.testing.assert_array_equal(np.asarray(relaxed.initial_states), np.zeros(N))
    assert relaxed.n_plays == N


def test_continuing_from_final_states_equals_whole_run(rng):
    u, r, w, x0 = _case(rng)
    k = 11
    whole, _, _ = _run(r, w, x0, u)
    _, _, mid = _run(r, w, x0, u[:k])
    second = pj.PIOperator(r, w, mid)(u[k:])
    np.testing.assert_allclose(second, np.asarray(whole)[k:], rtol=0, atol=1e-12)


def test_single_play_and_float32(rng):
    u, _, _, _ = _case(rng)
    op = pj.PIOperator(0.0, jnp.array([2.5]))
    np.testing.assert_allclose(op(u), 2.5 * u, rtol=0, atol=1e-12)
    u32, r, w, x0 = (a.astype(np.float32) for a in _case(rng))
    op32 = pj.PIOperator(r, w, x0)
    y = op32(u32)
    assert y.dtype == jnp.float32 and op32.regressor(u32).dtype == jnp.float32
    np.testing.assert_allclose(y, ref.pi(u32, r, w, x0), rtol=1e-5, atol=1e-4)


def test_vmap_across_threshold_sets_matches_python_loop(rng):
    u, _, _, _ = _case(rng)
    cases = [_case(rng)[1:] for _ in range(4)]
    R, W, X0 = (jnp.stack([c[i] for c in cases]) for i in range(3))

    @jax.jit
    @functools.partial(jax.vmap, in_axes=(0, 0, 0, None))
    def batched(r, w, x0, u):
        op = pj.PIOperator(r, w, x0)
        return op(u), op.regressor(u)

    Y, H = batched(R, W, X0, u)
    assert Y.shape == (4, T) and H.shape == (4, T, N)
    for b, (r, w, x0) in enumerate(cases):
        np.testing.assert_allclose(Y[b], ref.pi(u, r, w, x0), rtol=0, atol=1e-12)
        np.testing.assert_allclose(H[b], ref.play(u, r, x0), rtol=0, atol=1e-12)


@pytest.mark.parametrize("method", ["scan", "associative"])
def test_vmap_across_signals_matches_python_loop(rng, method):
    _, r, w, x0 = _case(rng)
    U = np.stack([_case(rng)[0] for _ in range(6)])
    op = pj.PIOperator(r, w, x0, method=method)

    @jax.jit
    @jax.vmap
    def batched(s):
        return op(s), op.regressor(s), pj.play(s, r, x0, method=method)

    Y, Hb, P = batched(U)
    for b in range(U.shape[0]):
        np.testing.assert_allclose(Y[b], ref.pi(U[b], r, w, x0), rtol=0, atol=1e-12)
        np.testing.assert_allclose(Hb[b], ref.play(U[b], r, x0), rtol=0, atol=1e-12)
        np.testing.assert_array_equal(np.asarray(P[b]), np.asarray(Hb[b]))


def test_operator_is_a_pytree_that_jit_accepts(rng):
    u, r, w, x0 = _case(rng)
    op = pj.PIOperator(r, w, x0)
    y = eqx.filter_jit(lambda o, s: o(s))(op, u)
    np.testing.assert_allclose(y, ref.pi(u, r, w, x0), rtol=0, atol=1e-12)
    leaves = jax.tree_util.tree_leaves(op)
    assert len(leaves) == 3  # thresholds, weights, initial states; the method is static


def test_abstract_operator_cannot_be_built():
    with pytest.raises(TypeError):
        pj.AbstractHysteresisOperator()


def test_construction_errors():
    r = jnp.array([0.0, 1.0, 2.0])
    w = jnp.ones(3)
    with pytest.raises(ValueError, match="must be strictly increasing"):
        pj.PIOperator(jnp.array([0.0, 2.0, 1.0]), w)
    with pytest.raises(ValueError, match="must be strictly increasing"):
        pj.PIOperator(jnp.array([0.0, 1.0, 1.0]), w)
    with pytest.raises(ValueError, match="must be non-negative, got min -1"):
        pj.PIOperator(jnp.array([-1.0, 1.0, 2.0]), w)
    with pytest.raises(ValueError, match="`thresholds` contains NaN or inf"):
        pj.PIOperator(jnp.array([0.0, jnp.inf, 2.0]), w)
    with pytest.raises(ValueError, match="`thresholds` is empty"):
        pj.PIOperator(jnp.zeros(0), jnp.zeros(0))
    with pytest.raises(ValueError, match="`thresholds` must be a scalar or a vector"):
        pj.PIOperator(jnp.zeros((2, 2)), w)
    with pytest.raises(ValueError, match="`weights` has 2 entries but there are 3 thresholds"):
        pj.PIOperator(r, jnp.ones(2))
    with pytest.raises(ValueError, match="`weights` must be a vector of 3 entries, got a scalar"):
        pj.PIOperator(r, 1.0)
    with pytest.raises(ValueError, match="`weights` contains NaN or inf"):
        pj.PIOperator(r, jnp.array([1.0, jnp.nan, 1.0]))
    with pytest.raises(ValueError, match="`initial_states` has 4 entries but there are 3"):
        pj.PIOperator(r, w, jnp.zeros(4))
    with pytest.raises(ValueError, match="`initial_states` contains NaN or inf"):
        pj.PIOperator(r, w, jnp.nan)
    with pytest.raises(ValueError, match="unknown play method 'fast'"):
        pj.PIOperator(r, w, method="fast")
    op = pj.PIOperator(r, w)
    with pytest.raises(ValueError, match="one signal of shape"):
        op(jnp.zeros((4, 2)))
    with pytest.raises(ValueError, match="`u` is empty"):
        op.regressor(jnp.zeros(0))
    with pytest.raises(ValueError, match="`u` contains NaN or inf"):
        op(jnp.array([0.0, jnp.nan]))


@jax.jit
def _traced(r, w, x0, u):
    return pj.PIOperator(r, w, x0)(u)


@pytest.mark.parametrize(
    "r, w, x0, match",
    [
        ([0.0, 2.0, 1.0], [1.0, 1.0, 1.0], 0.0, "`thresholds` must be strictly increasing"),
        ([0.0, -1.0, 1.0], [1.0, 1.0, 1.0], 0.0, "`thresholds` must be finite and non-negative"),
        ([0.0, 1.0, 2.0], [1.0, np.inf, 1.0], 0.0, "`weights` contains NaN or inf"),
        ([0.0, 1.0, 2.0], [1.0, 1.0, 1.0], np.nan, "`initial_states` contains NaN or inf"),
        ([0.0, 1.0, 2.0], [1.0, 1.0, 1.0], 0.0, "`u` contains NaN or inf"),
    ],
)
def test_traced_value_errors_under_jit(r, w, x0, match):
    u = jnp.zeros(6).at[2].set(jnp.nan if match.startswith("`u`") else 0.0)
    args = (jnp.asarray(r), jnp.asarray(w), jnp.asarray(x0), u)
    with pytest.raises(RuntimeError, match=match):
        jax.block_until_ready(_traced(*args))


def test_traced_valid_operator_runs_under_jit(rng):
    u, r, w, x0 = _case(rng, n=3)
    np.testing.assert_allclose(
        _traced(jnp.asarray(r), jnp.asarray(w), jnp.asarray(x0), jnp.asarray(u)[:6]),
        ref.pi(u[:6], r, w, x0),
        rtol=0,
        atol=1e-12,
    )
