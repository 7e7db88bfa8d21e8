"""The API accepts what NumPy and JAX users pass: NumPy integers for counts and lengths, new-style
and legacy PRNG keys, scalars alike for thresholds and weights; and says clearly what it refuses."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import piest_jax as pj

T_GRID = pj.time_grid(1.0, 1e-3)
U = pj.sine(T_GRID, 10.0, 5.0)
R = jnp.array([0.0, 10 / 3, 20 / 3])
H = pj.PIOperator(R, jnp.array([1.0, 3.0, 5.0])).regressor(U)

# Every public function taking a window (or a stride) of samples, called with Python ints.
WINDOWED = {
    "pe_level": lambda w, s: pj.pe_level(H, w, stride=s),
    "windowed_gram": lambda w, s: pj.windowed_gram(H, w, stride=s),
    "windowed_pe_levels": lambda w, s: pj.windowed_pe_levels(H, w, stride=s),
    "windowed_range": lambda w, s: pj.windowed_range(U, w, stride=s),
    "assumption1_ratio": lambda w, s: pj.assumption1_ratio(U, 20 / 3, w, stride=s),
    "window_starts": lambda w, s: pj.window_starts(1001, w, stride=s),
    "excited_plays": lambda w, s: pj.excited_plays(H, w, stride=s),
    "exact_condition": lambda w, s: pj.exact_condition(H, U, R, w, stride=s),
    "pe_margin": lambda w, s: pj.pe_margin(H, U, R, w, stride=s),
    "sharper_condition": lambda w, s: pj.sharper_condition(H, U, w, stride=s),
    "convergence_certificate": lambda w, s: pj.convergence_certificate(H, 1e6, 1e-3, w),
}


@pytest.mark.parametrize("name", list(WINDOWED))
def test_numpy_integers_are_whole_numbers(name):
    f = WINDOWED[name]
    expected = f(200, 10)
    got = f(np.int64(200), np.int32(10))
    for a, b in zip(jax.tree.leaves(expected), jax.tree.leaves(got)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    with pytest.raises(ValueError, match="window"):
        f(200.0, 10)
    with pytest.raises(ValueError, match="window"):
        f(True, 10)


def test_pe_map_takes_legacy_and_new_style_keys_alike():
    settings = pj.make_settings(n_samples=200, n_plays=3, window=50)
    new = pj.pe_map(jax.random.key(3), np.int64(7), settings, chunk=np.int32(7), quiet=True)
    legacy = pj.pe_map(jax.random.PRNGKey(3), 7, settings, quiet=True)
    legacy_arrays = legacy.arrays()
    assert new.arrays().keys() == legacy_arrays.keys()
    for k, v in new.arrays().items():
        np.testing.assert_array_equal(v, legacy_arrays[k], err_msg=k)
    np.testing.assert_array_equal(
        jax.random.key_data(pj.draw_keys(jax.random.PRNGKey(1), 0, 4)),
        jax.random.key_data(pj.draw_keys(jax.random.key(1), 0, 4)),
    )
    with pytest.raises(ValueError, match=r"`key` must be a PRNG key such as jax.random.key\(0\)"):
        pj.pe_map(np.zeros(3), 7, settings)
    with pytest.raises(ValueError, match="one PRNG key"):
        pj.pe_map(jax.random.split(jax.random.key(0), 2), 7, settings)


def test_a_scalar_weight_goes_with_a_scalar_threshold():
    u = jnp.array([0.0, 1.0, 3.0, 2.0])
    a = pj.PIOperator(0.0, 2.0)
    b = pj.PIOperator(jnp.array([0.0]), jnp.array([2.0]))
    np.testing.assert_array_equal(a(u), b(u))
    assert a.weights.shape == (1,)
    with pytest.raises(ValueError, match="`weights` must be a vector of 3 entries, got a scalar"):
        pj.PIOperator(R, 1.0)


@pytest.mark.parametrize("cls", [pj.ContinuousRLS, pj.ForgettingRLS, pj.NormalisedGradient])
def test_an_estimator_class_instead_of_an_instance_is_named(cls):
    with pytest.raises(ValueError, match=rf"`estimator` is the class {cls.__name__}, not an estimator"):
        pj.estimate(cls, H, U)
    with pytest.raises(ValueError, match=rf"`estimator` is the class {cls.__name__}"):
        pj.estimate_record(cls, np.asarray(U), np.asarray(U), [0.0, 1.0], dt=1e-3)
    with pytest.raises(ValueError, match="must be an estimator such as ContinuousRLS"):
        pj.estimate("rls", H, U)


def test_fit_pi_takes_numpy_integers_for_its_counts():
    t = np.arange(400) * 1e-3
    u = np.sin(2 * np.pi * 3 * t) * (1 + 0.5 * np.sin(2 * np.pi * 0.7 * t))
    y = np.asarray(pj.PIOperator([0.0, 0.3], [1.0, 0.5])(u))
    kwargs = dict(n_starts=2, max_steps=5, starts_at_once=1, key=jax.random.key(0))
    a = pj.fit_pi(u, y, 2, **kwargs)
    b = pj.fit_pi(u, y, np.int64(2), **{k: np.int64(v) if isinstance(v, int) else v for k, v in kwargs.items()})
    np.testing.assert_array_equal(np.asarray(a.thresholds), np.asarray(b.thresholds))
    with pytest.raises(ValueError, match="`max_steps` must be a positive whole number, got 2.5"):
        pj.fit_pi(u, y, 2, max_steps=2.5)


# Every public function taking a key, called with (new-style, legacy) keys of the same seed.
KEYED = {
    "draw_case": lambda k: pj.draw_case(k, "sine", jnp.asarray(T_GRID[:200]), 3),
    "run_batch": lambda k: (
        pj.run_batch(jnp.stack([U[:200], U[:200]]), jnp.ones((2, 3)), R, key=k, noise_std=0.1).final_weights
    ),
    "fit_pi": lambda k: (
        pj.fit_pi(np.asarray(U[:400]), np.asarray(H[:400].sum(axis=1)), 2, n_starts=3, max_steps=3, key=k).thresholds
    ),
    "hidden_effect_record": lambda k: pj.hidden_effect_record((), key=k, n_samples=300)[0].y,
}


@pytest.mark.parametrize("name", list(KEYED))
def test_every_key_taker_takes_both_kinds_and_names_a_wrong_one(name):
    f = KEYED[name]
    for a, b in zip(jax.tree.leaves(f(jax.random.key(5))), jax.tree.leaves(f(jax.random.PRNGKey(5)))):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    for bad in (0, np.zeros(3), jax.random.split(jax.random.key(0), 2)):
        with pytest.raises(ValueError, match=r"`key` must be (a PRNG key such as jax.random.key\(0\)|one PRNG key)"):
            f(bad)


def test_numpy_integers_in_fit_preisach_and_compare():
    t = np.arange(300) * 1e-3
    u = np.sin(2 * np.pi * 3 * t) * (1 + 0.5 * np.sin(2 * np.pi * 0.7 * t))
    y = np.asarray(pj.PIOperator([0.0, 0.3], [1.0, 0.5])(u))
    a = pj.fit_preisach(u, y, n_widths=3, n_centres=3, n_blocks=3, chunk=64)
    b = pj.fit_preisach(u, y, n_widths=np.int64(3), n_centres=np.int32(3), n_blocks=np.int64(3), chunk=np.int64(64))
    assert a.smoothness == b.smoothness
    np.testing.assert_array_equal(np.asarray(a.model.density), np.asarray(b.model.density))
    fit = pj.fit_pi(u, y, 2, n_starts=2, max_steps=5)
    c, d = pj.compare(fit, u, y, max_steps=5), pj.compare(fit, u, y, max_steps=np.int64(5))
    np.testing.assert_array_equal(np.asarray(c.prediction), np.asarray(d.prediction))
    with pytest.raises(ValueError, match="`max_steps` must be a positive whole number, got 5.0"):
        pj.compare(fit, u, y, max_steps=5.0)
