"""Persistent-excitation tools against brute-force NumPy window loops."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import piest_jax as pj

R = (0.0, 10 / 3, 20 / 3)
T = np.arange(1001) * 1e-3


def _regressor(u, r=R):
    return np.asarray(pj.PIOperator(r, np.ones(len(r))).regressor(u))


def _ref_gram(H, window, stride):
    out = []
    for s in range(0, H.shape[0] - window + 1, stride):
        Hw = H[s : s + window]
        out.append(sum(np.outer(h, h) for h in Hw) / window)
    return np.array(out)


def _ref_ratio(u, r_max, window, stride):
    vals = [
        (u[s : s + window].max() - u[s : s + window].min()) / (2 * r_max) for s in range(0, len(u) - window + 1, stride)
    ]
    return min(vals)


@pytest.mark.parametrize("window,stride", [(1, 1), (37, 1), (200, 50), (1001, 1), (64, 7)])
def test_windowed_gram_and_pe_level_match_loops(window, stride):
    u = 10 * np.sin(2 * np.pi * 5 * T) + 2 * np.sin(2 * np.pi * 13 * T)
    H = _regressor(u)
    ref = _ref_gram(H, window, stride)
    got = np.asarray(pj.windowed_gram(H, window, stride=stride))
    np.testing.assert_allclose(got, ref, rtol=1e-10, atol=1e-10)
    c1_ref = min(np.linalg.eigvalsh(g)[0] for g in ref)
    np.testing.assert_allclose(float(pj.pe_level(H, window, stride=stride)), c1_ref, atol=1e-9)
    assert np.asarray(pj.window_starts(len(T), window, stride=stride)).tolist() == list(
        range(0, len(T) - window + 1, stride)
    )


@settings(max_examples=25)
@given(
    st.lists(st.floats(-50, 50), min_size=1, max_size=60),
    st.integers(1, 60),
    st.integers(1, 9),
)
def test_assumption1_ratio_matches_loop(values, window, stride):
    u = np.asarray(values)
    window = min(window, len(u))
    got = float(pj.assumption1_ratio(u, 2.5, window, stride=stride))
    np.testing.assert_allclose(got, _ref_ratio(u, 2.5, window, stride), rtol=1e-12, atol=1e-12)


def test_windowed_range_per_column_and_excited_plays():
    u = np.concatenate([10 * np.sin(2 * np.pi * 5 * T[:500]), np.full(501, 1.0)])
    H = _regressor(u)
    rng_ref = np.array([H[s : s + 100].max(0) - H[s : s + 100].min(0) for s in range(0, 1001 - 100 + 1, 25)])
    np.testing.assert_allclose(pj.windowed_range(H, 100, stride=25), rng_ref, rtol=1e-12)
    moving = np.asarray(pj.excited_plays(H, 100, stride=25, atol=1e-12))
    assert moving[0].all()  # the sine drives every play
    assert not moving[-1].any()  # the constant tail leaves every play flat


def test_sine_paper_input_satisfies_assumption1_and_pe():
    u = 10 * np.sin(2 * np.pi * 5 * T)
    H = _regressor(u)
    assert float(pj.assumption1_ratio(u, R[-1], 200)) >= 1.0
    assert float(pj.pe_level(H, 200)) > 0.1
    chk = pj.lemma1_check(H[:200])
    assert bool(chk.independent) and int(chk.rank) == 3
    # σ_min² / T is the window's Gram eigenvalue (Lemma 1 as an identity)
    g = np.linalg.eigvalsh(H[:200].T @ H[:200] / 200)[0]
    np.testing.assert_allclose(float(chk.smallest_singular_value) ** 2 / 200, g, rtol=1e-9)


def test_small_amplitude_violates_pe():
    u = 2.0 * np.sin(2 * np.pi * 5 * T)  # below r_2 = 10/3: plays 2 and 3 never leave 0
    H = _regressor(u)
    assert float(pj.assumption1_ratio(u, R[-1], 200)) < 1.0
    assert abs(float(pj.pe_level(H, 200))) < 1e-12
    chk = pj.lemma1_check(H[:200])
    assert not bool(chk.independent)
    assert int(chk.rank) == 1


def test_lemma1_dependent_columns_detected():
    rng = np.random.default_rng(0)
    a = rng.normal(size=(50, 2))
    H = np.column_stack([a, a @ np.array([0.3, -1.2])])
    chk = pj.lemma1_check(H)
    assert int(chk.rank) == 2 and not bool(chk.independent)
    assert float(chk.smallest_singular_value) < 1e-12


def test_vmap_equals_loop():
    us = np.stack([a * np.sin(2 * np.pi * 5 * T) for a in (2.0, 5.0, 10.0)])
    Hs = np.stack([_regressor(u) for u in us])
    batched = jax.vmap(lambda H: pj.pe_level(H, 200, stride=10))(jnp.asarray(Hs))
    loop = [float(pj.pe_level(H, 200, stride=10)) for H in Hs]
    np.testing.assert_allclose(batched, loop, rtol=1e-12, atol=1e-14)
    rb = jax.vmap(lambda u: pj.assumption1_ratio(u, R[-1], 200))(jnp.asarray(us))
    np.testing.assert_allclose(rb, [_ref_ratio(u, R[-1], 200, 1) for u in us], rtol=1e-12)


def test_errors():
    H = _regressor(10 * np.sin(2 * np.pi * 5 * T))
    with pytest.raises(ValueError, match="between 1 and the signal length"):
        pj.windowed_gram(H, 2000)
    with pytest.raises(ValueError, match="stride"):
        pj.pe_level(H, 10, stride=0)
    with pytest.raises(ValueError, match="whole number"):
        pj.pe_level(H, 10.5)
    with pytest.raises(ValueError, match=r"shape \(T, n\)"):
        pj.windowed_gram(H[:, 0], 10)
    with pytest.raises(ValueError, match="NaN or inf"):
        pj.pe_level(np.where(np.arange(1001)[:, None] == 5, np.nan, H), 10)
    with pytest.raises(ValueError, match="`r_max` must be positive"):
        pj.assumption1_ratio(np.sin(T), 0.0, 10)
    with pytest.raises(ValueError, match="`rtol` must be non-negative"):
        pj.lemma1_check(H, rtol=-1.0)
