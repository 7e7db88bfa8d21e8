"""Play and stop against NumPy loops, scan against associative scan, and hypothesis properties."""

import functools
import warnings

import hypothesis.extra.numpy as hnp
import hypothesis.strategies as st
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import reference as ref
from hypothesis import given

import piest_jax as pj

T = 24
N = 4


@functools.partial(jax.jit, static_argnames="method")
def _play(u, r, x0, method="scan"):
    return pj.play(u, r, x0, method=method)


@functools.partial(jax.jit, static_argnames="method")
def _stop(u, r, e0, method="scan"):
    return pj.stop(u, r, e0, method=method)


def _random_case(rng, t=T, n=N, dtype=np.float64):
    u = rng.normal(0.0, 2.0, size=t).cumsum().astype(dtype)
    r = np.sort(rng.uniform(0.0, 3.0, size=n)).astype(dtype)
    r[0] = 0.0
    x0 = rng.normal(0.0, 3.0, size=n).astype(dtype)
    return u, r, x0


signals = hnp.arrays(np.float64, T, elements=st.floats(-50, 50, allow_subnormal=False))
banks = hnp.arrays(np.float64, N, elements=st.floats(0, 20, allow_subnormal=False))
states = hnp.arrays(np.float64, N, elements=st.floats(-60, 60, allow_subnormal=False))
varying_banks = hnp.arrays(np.float64, (T, N), elements=st.floats(0, 20, allow_subnormal=False))
# `method="kernel"` is a CPU path (refused on an accelerator backend, with a message).
ALL_METHODS = ["scan", "associative", "auto"] + (["kernel"] if jax.default_backend() == "cpu" else [])


def _play_varying_loop(u, r, x0):
    """Play outputs (T, n) for thresholds r (T, n) that vary over time, by the defining loop."""
    x = np.broadcast_to(np.asarray(x0, np.float64), r.shape[1:]).copy()
    out = np.empty(r.shape)
    for t in range(len(u)):
        for j in range(r.shape[1]):
            lo, hi = u[t] - r[t, j], u[t] + r[t, j]
            x[j] = lo if x[j] < lo else (hi if x[j] > hi else x[j])
        out[t] = x
    return out


def _stop_varying_loop(u, r, e0):
    """Stop outputs (T, n) by e_t = clamp(e_{t-1} + u_t - u_{t-1}, -r_t, r_t), r (T, n)."""
    e = np.broadcast_to(np.asarray(e0, np.float64), r.shape[1:]).copy()
    out = np.empty(r.shape)
    prev = u[0]
    for t in range(len(u)):
        for j in range(r.shape[1]):
            e[j] = min(r[t, j], max(-r[t, j], e[j] + u[t] - prev))
        prev = u[t]
        out[t] = e
    return out


def _varying_case(rng, t=T, n=N, dtype=np.float64):
    u, r, x0 = _random_case(rng, t, n, dtype)
    # Thresholds that widen and narrow with the input's rate, as rate-dependent hysteresis has them.
    rate = np.abs(np.diff(u.astype(np.float64), prepend=u[0]))
    return u, (r[None, :] * (1 + rate[:, None])).astype(dtype), x0


@pytest.mark.parametrize("method", ["scan", "associative"])
def test_play_matches_numpy_loop(rng, method):
    for _ in range(5):
        u, r, x0 = _random_case(rng)
        np.testing.assert_allclose(_play(u, r, x0, method), ref.play(u, r, x0), rtol=0, atol=1e-12)


@pytest.mark.parametrize("method", ["scan", "associative"])
def test_scalar_threshold_and_scalar_state(rng, method):
    u, _, _ = _random_case(rng)
    out = _play(u, 1.5, -0.7, method)
    assert out.shape == (T,)
    np.testing.assert_allclose(out, ref.play(u, 1.5, -0.7)[:, 0], rtol=0, atol=1e-12)
    bank = _play(u, jnp.array([0.0, 1.5]), -0.7, method)
    assert bank.shape == (T, 2)
    np.testing.assert_allclose(bank[:, 0], u, rtol=0, atol=0)


@pytest.mark.parametrize("method", ["scan", "associative"])
def test_stop_matches_direct_stop_recursion(rng, method):
    for _ in range(5):
        u, r, _ = _random_case(rng)
        e0 = rng.uniform(-1, 1, size=N) * r
        got = _stop(u, r, e0, method)
        np.testing.assert_allclose(got, ref.stop(u, r, e0), rtol=0, atol=1e-12)
        played = _play(u, r, u[0] - e0, method)
        np.testing.assert_allclose(got + played, np.repeat(u[:, None], N, 1), atol=1e-12)


@jax.jit
def _both_methods(u, r, x0):
    return tuple((pj.play(u, r, x0, method=m), pj.stop(u, r, 0.0, method=m)) for m in ("scan", "associative"))


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_scan_and_associative_bit_identical(rng, dtype):
    for t in (1, 2, 3, 37):
        u, r, x0 = _random_case(rng, t=t, dtype=dtype)
        (a, s1), (b, s2) = _both_methods(u, r, x0)
        assert a.dtype == b.dtype == dtype
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
        np.testing.assert_array_equal(np.asarray(s1), np.asarray(s2))


def test_play_step_is_one_clamp():
    x = pj.play_step(jnp.array([5.0, -5.0, 0.3]), 0.0, jnp.array([1.0, 1.0, 1.0]))
    np.testing.assert_array_equal(np.asarray(x), [1.0, -1.0, 0.3])


@given(signals, banks, states)
def test_output_within_band(u, r, x0):
    for method in ("scan", "associative"):
        x = np.asarray(_play(u, r, x0, method))
        assert np.all(x >= u[:, None] - r) and np.all(x <= u[:, None] + r)
    e = np.asarray(_stop(u, r, 0.0))
    assert np.all(np.abs(e) <= r)


@given(signals, states)
def test_zero_threshold_gives_input(u, x0):
    for method in ("scan", "associative"):
        out = np.asarray(_play(u, np.zeros(N), x0, method))
        np.testing.assert_array_equal(out, np.repeat(u[:, None], N, axis=1))


@given(signals, banks, states, st.sampled_from([1, 9, T - 1]))
def test_two_pieces_equal_whole(u, r, x0, k):
    whole = np.asarray(_play(u, r, x0))
    first = np.asarray(_play(u[:k], r, x0))
    second = np.asarray(_play(u[k:], r, first[-1]))
    np.testing.assert_array_equal(np.concatenate([first, second]), whole)
    e_whole = np.asarray(_stop(u, r, 0.0))
    e_second = np.asarray(_stop(u[k - 1 :], r, e_whole[k - 1]))
    np.testing.assert_allclose(e_second[1:], e_whole[k:], rtol=0, atol=1e-12)


fractions_ = hnp.arrays(np.float64, 5, elements=st.floats(0, 1))


@given(signals, banks, states, st.integers(0, T - 2), fractions_)
def test_rate_independence(u, r, x0, k, fractions):
    # Samples inserted between u_k and u_{k+1} lie on a monotone stretch.
    lo, hi = u[k], u[k + 1]
    extra = np.clip(lo + np.sort(fractions) * (hi - lo), min(lo, hi), max(lo, hi))
    if hi < lo:
        extra = np.clip(lo + np.sort(fractions) * (hi - lo), hi, lo)
    dense = np.concatenate([u[: k + 1], extra, u[k + 1 :]])
    old = np.r_[np.arange(k + 1), np.arange(k + 1, T) + len(extra)]
    for method in ("scan", "associative"):
        np.testing.assert_array_equal(np.asarray(_play(dense, r, x0, method))[old], np.asarray(_play(u, r, x0, method)))


def test_shape_and_value_errors():
    u = jnp.zeros(5)
    with pytest.raises(ValueError, match="one signal of shape"):
        pj.play(jnp.zeros((5, 2)), 1.0)
    with pytest.raises(ValueError, match="is empty"):
        pj.play(jnp.zeros(0), 1.0)
    with pytest.raises(ValueError, match="non-negative"):
        pj.play(u, jnp.array([0.0, -1.0]))
    with pytest.raises(ValueError, match="NaN or inf"):
        pj.play(u, jnp.array([0.0, jnp.nan]))
    with pytest.raises(ValueError, match="has 3 entries but there are 2 thresholds"):
        pj.play(u, jnp.array([0.0, 1.0]), jnp.zeros(3))
    with pytest.raises(ValueError, match="but the threshold is a scalar"):
        pj.play(u, 1.0, jnp.zeros(3))
    with pytest.raises(ValueError, match="`u` contains NaN or inf"):
        pj.play(jnp.array([0.0, jnp.nan, 1.0]), 1.0)
    with pytest.raises(ValueError, match="`u` contains NaN or inf"):
        pj.stop(jnp.array([0.0, jnp.inf]), 1.0)
    with pytest.raises(ValueError, match="unknown play method"):
        pj.play(u, 1.0, method="fast")
    with pytest.raises(ValueError, match="scalar or a vector"):
        pj.stop(u, jnp.ones((2, 2)))


def test_traced_value_errors_under_jit():
    with pytest.raises(RuntimeError, match="must be finite and non-negative"):
        jax.block_until_ready(_play(jnp.zeros(T), -jnp.ones(N), jnp.zeros(N)))
    with pytest.raises(RuntimeError, match="`u` contains NaN or inf"):
        jax.block_until_ready(_play(jnp.zeros(T).at[3].set(jnp.nan), jnp.ones(N), jnp.zeros(N)))


def test_auto_takes_the_associative_scan_on_an_accelerator(monkeypatch, rng):
    from piest_jax._models import creep as _creep
    from piest_jax._operators import play as _play

    assert _play.resolved("scan") == "scan" and _play.resolved("associative") == "associative"
    on_cpu = _play.resolved("auto")
    assert on_cpu == ("kernel" if jax.default_backend() == "cpu" and pj.kernel_available() else "scan")
    with pytest.raises(ValueError, match="unknown play method 'fast'"):
        _play.resolved("fast")
    # What an accelerator backend sees (the sequential scan there is a device loop, one sample
    # per pass); the outputs are the same to the last bit.
    monkeypatch.setattr(_play, "on_accelerator", lambda: True)
    assert _play.resolved("auto") == "associative"
    u = jnp.asarray(rng.standard_normal(173))  # a length no other test traces
    r = jnp.asarray([0.0, 0.2, 0.7])
    op = pj.PIOperator(r, [1.0, 0.5, 0.25], method="auto")
    scan = pj.PIOperator(r, [1.0, 0.5, 0.25], method="scan")
    assert " scan[" not in str(jax.make_jaxpr(op)(u)) and " scan[" in str(jax.make_jaxpr(scan)(u))
    np.testing.assert_array_equal(op.regressor(u), scan.regressor(u))
    np.testing.assert_allclose(op(u), scan(u), rtol=1e-14)
    monkeypatch.setattr(_creep, "on_accelerator", lambda: True)
    a, z0 = jnp.asarray([0.5, 0.9]), jnp.zeros(2)
    assert " scan[" not in str(jax.make_jaxpr(lambda u: _creep.lag_states(u, a, z0, method="auto"))(u))
    np.testing.assert_allclose(
        _creep.lag_states(u, a, z0, method="auto"), _creep.lag_states(u, a, z0, method="scan"), rtol=1e-12, atol=1e-14
    )


@given(signals, varying_banks, states)
def test_time_varying_thresholds_match_numpy_loop(u, r, x0):
    expected = _play_varying_loop(u, r, x0)
    for method in ALL_METHODS:
        # max and min only select between u_t - r_t, u_t + r_t and the state: no rounding to differ.
        np.testing.assert_array_equal(np.asarray(_play(u, r, x0, method)), expected)


@given(signals, varying_banks, states)
def test_time_varying_stop_matches_direct_stop_recursion(u, r, x0):
    e0 = np.clip(x0, -r[0], r[0])
    for method in ("scan", "associative"):
        got = np.asarray(_stop(u, r, e0, method))
        assert np.all(np.abs(got) <= r)
        np.testing.assert_allclose(got, _stop_varying_loop(u, r, e0), rtol=0, atol=1e-12)


@given(signals, varying_banks, states, st.sampled_from([1, 9, T - 1]))
def test_time_varying_two_pieces_equal_whole(u, r, x0, k):
    whole = np.asarray(_play(u, r, x0))
    first = np.asarray(_play(u[:k], r[:k], x0))
    second = np.asarray(_play(u[k:], r[k:], first[-1]))
    np.testing.assert_array_equal(np.concatenate([first, second]), whole)


@pytest.mark.parametrize("method", ALL_METHODS)
def test_constant_thresholds_given_per_sample_are_bit_identical(rng, method):
    for t in (1, 2, 37):
        u, r, x0 = _random_case(rng, t=t)
        per_sample = np.broadcast_to(r, (t, N))
        np.testing.assert_array_equal(np.asarray(_play(u, per_sample, x0, method)), np.asarray(_play(u, r, x0, method)))
        np.testing.assert_array_equal(
            np.asarray(_stop(u, per_sample, 0.0, method)), np.asarray(_stop(u, r, 0.0, method))
        )
        # Eager calls take the same paths.
        np.testing.assert_array_equal(
            np.asarray(pj.play(u, per_sample, x0, method=method)), np.asarray(pj.play(u, r, x0, method=method))
        )


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_scan_and_associative_bit_identical_with_time_varying_thresholds(rng, dtype):
    for t in (1, 2, 3, 37):
        u, r, x0 = _varying_case(rng, t=t, dtype=dtype)
        (a, s1), (b, s2) = _both_methods(u, r, x0)
        assert a.dtype == b.dtype == dtype and a.shape == (t, N)
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
        np.testing.assert_array_equal(np.asarray(s1), np.asarray(s2))


def test_time_varying_thresholds_take_the_scan_on_a_cpu(rng):
    from piest_jax._operators import play as _play_module

    if jax.default_backend() != "cpu":
        pytest.skip("the kernel and its fallback are CPU paths")
    for method in ("kernel", "auto"):
        assert _play_module.resolved(method, time_varying=True) == "scan"
    u, r, x0 = _varying_case(rng)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no fallback warning: the kernel was never the path
        for method in ("kernel", "auto"):
            jaxpr = str(jax.make_jaxpr(lambda u, r, x0, m=method: pj.play(u, r, x0, method=m))(u, r, x0))
            assert " scan[" in jaxpr and "ffi_call" not in jaxpr
            np.testing.assert_array_equal(
                np.asarray(pj.play(u, r, x0, method=method)), np.asarray(pj.play(u, r, x0, method="scan"))
            )


def test_time_varying_shape_and_value_errors():
    u = jnp.zeros(5)
    with pytest.raises(ValueError, match=r"or \(5, n\) for thresholds that vary over time .* got shape \(4, 2\)"):
        pj.play(u, jnp.ones((4, 2)))
    with pytest.raises(ValueError, match=r"or \(5, n\) for thresholds that vary over time .* got shape \(5, 2, 1\)"):
        pj.play(u, jnp.ones((5, 2, 1)))
    with pytest.raises(ValueError, match=r"`r` is empty: its shape \(5, 0\) holds no play"):
        pj.play(u, jnp.ones((5, 0)))
    with pytest.raises(ValueError, match="`r` must be non-negative, got min -1"):
        pj.play(u, jnp.ones((5, 2)).at[3, 1].set(-1.0))
    with pytest.raises(ValueError, match="`r` contains NaN or inf"):
        pj.stop(u, jnp.ones((5, 2)).at[0, 0].set(jnp.inf))
    with pytest.raises(ValueError, match="has 3 entries but there are 2 thresholds"):
        pj.play(u, jnp.ones((5, 2)), jnp.zeros(3))
    with pytest.raises(ValueError, match="`u` contains NaN or inf"):
        pj.play(u.at[2].set(jnp.nan), jnp.ones((5, 2)), method="auto")
    with pytest.raises(RuntimeError, match="must be finite and non-negative"):
        jax.block_until_ready(_play(jnp.zeros(T), -jnp.ones((T, N)), jnp.zeros(N)))
    with pytest.raises(RuntimeError, match="`u` contains NaN or inf"):
        jax.block_until_ready(_play(jnp.zeros(T).at[3].set(jnp.nan), jnp.ones((T, N)), jnp.zeros(N), "auto"))
