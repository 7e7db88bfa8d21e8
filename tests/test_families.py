"""Random input families, thresholds, initial states and weights: reproducible, in range, valid."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from piest_jax._excitation import draw as F
from piest_jax._excitation.families import DEFAULT_FAMILIES
from piest_jax._excitation.family import AMPLITUDE_RANGE, AbstractInputFamily

T = jnp.arange(800) * 0.01
N_PLAYS = 5


KEYS = jax.random.split(jax.random.key(3), 40)


@jax.jit
def _draw_all(keys):
    return {f: jax.vmap(lambda k, f=f: F.draw_case(k, f, T, N_PLAYS))(keys) for f in F.FAMILIES}


@pytest.fixture(scope="module")
def cases():
    """(u, r, x0, w) for 40 keys of every family, from one compiled program."""
    return {f: [np.asarray(a) for a in v] for f, v in _draw_all(KEYS).items()}


def test_case_is_a_function_of_key(cases):
    perm = np.random.default_rng(0).permutation(len(KEYS))
    again = _draw_all(KEYS[perm])
    for f in F.FAMILIES:
        for batched, permuted in zip(cases[f], again[f]):
            np.testing.assert_array_equal(batched[perm], np.asarray(permuted))
    other = _draw_all(jax.random.split(jax.random.key(4), 40))
    for f in F.FAMILIES:
        # initial states are all zero half the time, so compare the input, thresholds, weights
        for i in (0, 1, 3):
            a, b = cases[f][i], other[f][i]
            assert not np.any(np.all(a == np.asarray(b), axis=tuple(range(1, a.ndim)))), f


def test_unbatched_draw_matches_the_batch(cases):
    single = jax.jit(F.draw_case, static_argnums=(1, 3))(KEYS[7], "noise", T, N_PLAYS)
    for batched, one in zip(cases["noise"], single):
        # vmap may fuse differently: equal up to rounding
        np.testing.assert_allclose(batched[7], np.asarray(one), rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("family", F.FAMILIES)
def test_inputs_are_finite_bounded_and_vary(family, cases):
    u, r, _, _ = cases[family]
    r_max = r[:, -1]
    assert np.all(np.isfinite(u))
    # offset within ±r_max, excursion within the largest amplitude 4 r_max
    hi = (1 + AMPLITUDE_RANGE[1]) * r_max * (1 + 1e-9)
    assert np.all(np.max(np.abs(u), axis=1) <= hi)
    assert np.all(np.ptp(u, axis=1) > 0)
    # the amplitude law covers both sides of Assumption 1 (peak-to-peak 2 r_max)
    ratio = np.ptp(u, axis=1) / (2 * r_max)
    assert ratio.min() < 1 < ratio.max()


def test_thresholds_and_states(cases):
    for family, (u, r, x0, w) in cases.items():
        assert np.all(np.diff(r, axis=1) >= 0), family
        assert np.all((r[:, -1] >= 0.5) & (r[:, -1] <= 2.0))
        assert np.all(r[:, 0] >= 0)
        assert np.all((w >= 0.5) & (w <= 5.0))
        zero = np.all(x0 == 0, axis=1)
        # Within r of u(0) up to rounding: u(0) may be computed twice in the compiled program
        # (once for the input, once for the states), an ulp apart, which matters where r = 0.
        slack = 4 * np.finfo(float).eps * np.abs(u[:, :1])
        inside = np.all(np.abs(x0 - u[:, :1]) <= r * (1 + 1e-12) + slack, axis=1)
        assert np.all(zero | inside), family
    r_all = np.concatenate([c[1] for c in cases.values()])
    x_all = np.concatenate([c[2] for c in cases.values()])
    # both a zero first threshold and zero initial states occur, about half the time each
    assert 0.3 < np.mean(r_all[:, 0] == 0) < 0.7
    assert 0.3 < np.mean(np.all(x_all == 0, axis=1)) < 0.7


def test_decaying_fails_assumption_late(cases):
    u = cases["decaying"][0]
    early = np.ptp(u[:, :100], axis=1)
    late = np.ptp(u[:, -100:], axis=1)
    assert np.all(late < early)


def test_noise_is_band_limited(cases):
    u = cases["noise"][0]
    spectrum = np.abs(np.fft.rfft(u - u.mean(axis=1, keepdims=True), axis=1))
    freqs = np.fft.rfftfreq(u.shape[1], 0.01)
    # the cut-off is at most 2 * 5 Hz: nothing above 10 Hz (Nyquist is 50 Hz)
    assert np.max(spectrum[:, freqs > 10.5]) < 1e-9 * np.max(spectrum)


def test_key_based_helpers_match_ranges():
    @jax.jit
    def helpers(key):
        r = F.draw_thresholds(key, 6)
        return r, F.draw_initial_states(key, r, 0.3), F.draw_input(key, "sine", T, 1.0)

    r, x0, u = helpers(jax.random.key(0))
    assert r.shape == (6,) and np.all(np.diff(np.asarray(r)) >= 0)
    assert np.all(x0 == 0) or np.all(np.abs(np.asarray(x0) - 0.3) <= np.asarray(r))
    assert u.shape == T.shape and u.dtype == T.dtype
    w = F.draw_weights(jax.random.key(0), 4)
    assert np.all((np.asarray(w) >= 0.5) & (np.asarray(w) <= 5))


def test_dtype_follows_the_grid():
    t32 = jnp.arange(100, dtype=jnp.float32) * 0.01
    for a in jax.jit(F.draw_case, static_argnums=(1, 3))(jax.random.key(1), "chirp", t32, 3):
        assert a.dtype == jnp.float32


def test_bad_arguments():
    key = jax.random.key(0)
    with pytest.raises(ValueError, match="unknown input family 'square'"):
        F.draw_case(key, "square", T, 3)
    with pytest.raises(ValueError, match="unknown input family 99"):
        F.family_indices([99])
    with pytest.raises(ValueError, match="no input family"):
        F.family_indices([])
    with pytest.raises(ValueError, match="number of plays must be a positive whole number"):
        F.draw_case(key, "sine", T, 0)
    with pytest.raises(ValueError, match="number of plays"):
        F.draw_thresholds(key, 2.5)
    with pytest.raises(ValueError, match="time grid of at least two samples"):
        F.draw_input(key, "sine", jnp.zeros((3, 2)), 1.0)


def test_registry_is_consistent():
    assert F.FAMILIES == tuple(F.FAMILY)
    for name, fam in F.FAMILY.items():
        assert fam.name == name and type(fam).__module__.endswith(f"families.{name}")  # one module each
    assert set(F.FAMILIES) - set(DEFAULT_FAMILIES) == {"ramp", "touch", "nested"}
    # Maps record families by index: the listing order of the shipped families does not move.
    old = ("sine", "multisine", "noise", "chirp", "triangle", "decaying", "steps", "ramp", "touch", "nested")
    assert F.FAMILIES[: len(old)] == old
    with pytest.raises(TypeError, match="does not define name, listed"):
        type("Nameless", (AbstractInputFamily,), {})
    with pytest.raises(TypeError, match="does not define listed"):
        type("Unlisted", (AbstractInputFamily,), {"name": "unlisted"})


@pytest.mark.parametrize("family", F.FAMILIES)
def test_each_family_reads_only_its_own_uniforms(family):
    # draw_case hands the uniforms after a family's own to the thresholds, states and weights:
    # a family that read past its count would correlate its input with them.
    fam = F.FAMILY[family]
    t = jnp.asarray(T)
    r = jnp.asarray([0.0, 0.4, 1.1])
    v = jax.random.uniform(jax.random.key(5), (fam.n_uniforms(t.shape[0]),), t.dtype)
    u = fam.input(v, t, r)
    for junk in (0.0, 0.99):
        longer = jnp.concatenate([v, jnp.full(7, junk, t.dtype)])
        np.testing.assert_array_equal(np.asarray(fam.input(longer, t, r)), np.asarray(u))
    assert u.shape == t.shape and np.ptp(np.asarray(u)) > 0
