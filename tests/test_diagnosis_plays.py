"""The diagnosis's play basis is the play operator: equal to the float64 loop it replaced, bit for bit.

`basis.plays` runs the operator batched over initial states and sub-sampled at `keep`; every
diagnosis result rests on these columns, so the reference below is the NumPy loop the diagnosis
used before, kept here verbatim, and the two must agree to the last bit on constant and
time-varying thresholds, several batches of initial states and several `keep` patterns.
"""

import jax
import numpy as np
import pytest
from compile_count import Compiles
from hypothesis import given, settings
from hypothesis import strategies as st

from piest_jax._diagnosis import basis as _basis


def _loop_plays(g, r, x0, keep=None):
    """Play outputs (C, T, n) or (C, len(keep), n): one clamp per sample for all C state sets."""
    g = np.asarray(g, float)
    x = np.array(x0, float)
    rr = np.broadcast_to(np.asarray(r, float), (len(g), x.shape[-1]))
    lo, hi = g[:, None] - rr, g[:, None] + rr
    slot = np.full(len(g), -1)
    slot[np.arange(len(g)) if keep is None else np.asarray(keep)] = np.arange(len(g) if keep is None else len(keep))
    out = np.empty((len(g) if keep is None else len(keep), x.shape[0], x.shape[1]))
    for i in range(len(g)):
        np.maximum(x, lo[i], out=x)
        np.minimum(x, hi[i], out=x)
        if slot[i] >= 0:
            out[slot[i]] = x
    return out.transpose(1, 0, 2)


def _input(rng, n):
    # A random walk in normalised units with the holds and reversals a record has.
    return np.cumsum(rng.normal(0.0, 0.15, size=n) * (rng.uniform(size=n) > 0.2))


def _rate_thresholds(rng, g):
    step = np.abs(np.diff(g, prepend=g[0]))
    rho = step / max(step.max(), 1e-300)
    k, p = rng.uniform(0.1, 4.0), rng.choice([0.5, 1.0])
    if rng.uniform() < 0.5:
        return _basis.THRESHOLDS[None, :] * (1 + k * rho[:, None] ** p)
    return _basis.THRESHOLDS[None, :] + 0.1 * k * rho[:, None] ** p


def _keeps(rng, n):
    # Increasing, distinct positions, as `turning_samples` gives them (the loop needs them distinct).
    every = np.arange(0, n, 3)
    sparse = np.sort(rng.choice(n, size=max(1, n // 5), replace=False))
    return [None, every, sparse, np.array([n - 1]), np.unique([0, n - 1])]


@settings(max_examples=20, deadline=None)
@given(st.integers(0, 2**32 - 1), st.sampled_from([1, 2, 7, 200, 511, 512, 513]), st.sampled_from([1, 3, 34]))
def test_plays_equal_the_loop_bit_for_bit(seed, n, c):
    rng = np.random.default_rng(seed)
    g = _input(rng, n)
    x0 = rng.uniform(-1.5, 1.5, size=(c, _basis.N_PLAYS))
    for r in (_basis.THRESHOLDS, _rate_thresholds(rng, g)):
        for keep in _keeps(rng, n):
            got, expected = _basis.plays(g, r, x0, keep), _loop_plays(g, r, x0, keep)
            assert got.shape == expected.shape and got.dtype == np.float64
            np.testing.assert_array_equal(got, expected)


def test_plays_on_the_turning_samples_of_a_record(rng):
    # The sub-sampled search's own layout: plays on the kept plus turning samples, read at `keep`.
    t = np.arange(6000) * 1e-3
    u = np.sin(2 * np.pi * 1.3 * t) * (0.6 + 0.4 * np.sin(2 * np.pi * 0.2 * t)) + 0.01 * rng.normal(size=len(t))
    index, keep = _basis.turning_samples(u, 3)
    g = u[index]
    x0 = np.stack([np.full(_basis.N_PLAYS, g[0]), _basis.history_states(g[0], (0.8, -0.4))])
    for r in (_basis.THRESHOLDS, _rate_thresholds(rng, g)):
        np.testing.assert_array_equal(_basis.plays(g, r, x0, keep), _loop_plays(g, r, x0, keep))


def test_plays_follow_the_default_precision_and_return_float64(rng):
    # The library leaves JAX's precision to its user: without x64 the plays run in float32, whose
    # rounding (not the recurrence) is all that separates them from the float64 loop.
    g = _input(rng, 300) * (1 + 1e-9)
    x0 = rng.uniform(-1, 1, size=(2, _basis.N_PLAYS))
    r = _rate_thresholds(rng, g)
    with jax.enable_x64(False):
        got = _basis.plays(g, r, x0)
    assert got.dtype == np.float64
    ref = _loop_plays(g, r, x0)
    assert not np.array_equal(got, ref)  # float32 values, not the float64 loop's
    np.testing.assert_allclose(got, ref, rtol=0, atol=4 * np.finfo(np.float32).eps * np.max(np.abs(ref)))


def test_plays_return_a_fresh_writable_array(rng):
    g = _input(rng, 50)
    out = _basis.plays(g, _basis.THRESHOLDS, np.zeros((1, _basis.N_PLAYS)))
    assert out.flags.writeable
    out[:] = 0.0  # the caller's to change
    np.testing.assert_array_equal(
        _basis.plays(g, _basis.THRESHOLDS, np.zeros((1, _basis.N_PLAYS))),
        _loop_plays(g, _basis.THRESHOLDS, np.zeros((1, _basis.N_PLAYS))),
    )


@pytest.mark.parametrize("varying", [False, True])
def test_nearby_lengths_compile_once(rng, varying):
    # The search calls the plays hundreds of times on one record, and nearby records differ in
    # length by a few samples: neither may compile a program per call.
    def call(n):
        g = _input(rng, n)
        r = _rate_thresholds(rng, g) if varying else _basis.THRESHOLDS
        return _basis.plays(g, r, np.zeros((2, _basis.N_PLAYS)), np.arange(0, n, 4))

    call(1900)
    with Compiles() as compiles:
        for n in (1900, 1901, 1950, 2040):
            call(n)
    assert compiles.count == 0
