"""Starts solved in batches: the same as all at once, for every batch size and for outputs with
a zero-size axis (a one-play fit has no threshold increments)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import piest_jax as pj
from piest_jax._identification.batches import map_in_batches

jax.config.update("jax_enable_x64", True)


def _fn(x):
    # Outputs of several shapes, one with a zero-size axis.
    return {"sum": jnp.sum(x), "scaled": 2.0 * x, "empty": x[:0]}, jnp.cumsum(x)


@settings(max_examples=25, deadline=None)
@given(n=st.integers(1, 9), batch=st.integers(1, 11))
def test_map_in_batches_equals_vmap(n, batch):
    xs = jnp.asarray(np.random.default_rng(n).normal(size=(n, 3)))
    want = jax.vmap(_fn)(xs)
    got = map_in_batches(_fn, xs, batch)
    for a, b in zip(jax.tree.leaves(want), jax.tree.leaves(got)):
        assert a.shape == b.shape
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_map_in_batches_refuses_a_batch_below_one():
    with pytest.raises(ValueError, match="`batch` must be a positive whole number"):
        map_in_batches(_fn, jnp.ones((3, 2)), 0)


@pytest.fixture(scope="module")
def one_play_record():
    u = 2.0 * np.sin(np.linspace(0.0, 20.0, 400))
    return u, np.tanh(u) + 0.3 * u


@pytest.mark.parametrize("fit", [pj.fit_pi, pj.fit_gpi], ids=["pi", "gpi"])
def test_one_play_fit_in_batches_equals_all_at_once(one_play_record, fit):
    # Three starts one at a time, two at a time (a remainder of one), and all together.
    u, y = one_play_record
    kw = dict(n_starts=3, key=jax.random.key(0), max_steps=30)
    whole = fit(u, y, 1, **kw)
    for b in (1, 2):
        part = fit(u, y, 1, starts_at_once=b, **kw)
        np.testing.assert_allclose(part.start_rmse, whole.start_rmse, rtol=1e-9, atol=1e-14)
        np.testing.assert_allclose(part.rmse, whole.rmse, rtol=1e-9, atol=1e-14)


def test_gpi_refuses_starts_at_once_below_one(one_play_record):
    u, y = one_play_record
    with pytest.raises(ValueError, match="`starts_at_once` must be a positive whole number"):
        pj.fit_gpi(u, y, 2, starts_at_once=0)
