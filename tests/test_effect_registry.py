"""The effect registry: every effect is one module whose NumPy and JAX models agree."""

import jax
import numpy as np
import pytest

from piest_jax._diagnosis import basis as _basis
from piest_jax._diagnosis import hidden as _hidden
from piest_jax._diagnosis import model as _model
from piest_jax._diagnosis import refine as _refine
from piest_jax._diagnosis.effect import AbstractEffect
from piest_jax._diagnosis.effects import EFFECT, EFFECTS, RECORD_SPECIFIC, chain, check_names
from piest_jax._diagnosis.scaling import Prepared

T, DT = 600, 1e-3


def _record():
    t = np.arange(T) * DT
    u = 0.9 * np.sin(2 * np.pi * 3 * t) * np.exp(-t / 2) + 0.1 * np.sin(2 * np.pi * 11 * t)
    return Prepared(u, np.zeros(T), t, rate_scale=20.0, period=0.33)


def test_registry_is_consistent():
    assert EFFECTS == tuple(EFFECT) and len(EFFECTS) == len(set(EFFECTS))
    assert len({e.rank for e in EFFECT.values()}) == len(EFFECTS)  # one order along the chain
    for name, e in EFFECT.items():
        assert e.name == name and e.summary and e.n_params >= 1
        assert type(e).__module__.endswith(f"effects.{name}")  # one module per effect
    assert set(RECORD_SPECIFIC) == {"initial_state", "offset_drift"}
    # The search tries and reports candidates in this order: the shipped effects keep theirs.
    old = ("initial_state", "delay", "linear_dynamics", "rate_dependence", "creep", "asymmetry", "offset_drift")
    assert EFFECTS[: len(old)] == old
    assert [e.name for e in chain(["offset_drift", "delay", "asymmetry"])] == ["delay", "asymmetry", "offset_drift"]
    with pytest.raises(ValueError, match="unknown effect 'magic'"):
        check_names(["delay", "magic"])


def test_an_effect_must_state_what_it_is():
    with pytest.raises(TypeError, match="does not define summary, rank, listed, n_params"):
        type("Half", (AbstractEffect,), {"name": "half"})


def _coefficients(cfg, n_out, rng):
    n_own = _model.n_linear(cfg) - _basis.N_PLAYS - 1 + n_out
    w = np.concatenate([rng.uniform(0.2, 1.0, _basis.N_PLAYS) / 8, [0.1], rng.normal(0, 0.1, n_own)])
    for name, sl in _model.output_slices(cfg).items():
        if EFFECT[name].positive:
            w[sl] = np.abs(w[sl])
    return w


@pytest.mark.parametrize("name", EFFECTS)
def test_each_effect_jax_model_matches_its_numpy_model(name):
    # A grid value from the effect's own grid, so a newly registered effect is checked too.
    p = _record()
    values = EFFECT[name].grid(p)
    cfg = {name: values[len(values) // 2]}
    X = _model.linear_part(p, cfg)
    assert X.shape[1] == _model.n_linear(cfg) == _basis.N_PLAYS + 1 + EFFECT[name].n_play_terms(cfg[name])
    n_out = _model.output_terms(p, cfg, X[:, 0], (0.0, 1.0)).shape[1]
    assert n_out == EFFECT[name].n_columns(cfg[name])
    w = _coefficients(cfg, n_out, np.random.default_rng(3))
    norm = (0.05, 0.7)
    ref = _model.predict(p, cfg, w, w, norm)
    assert np.ptp(ref - _model.predict(p, {}, w[: _basis.N_PLAYS + 1], w, norm)) > 1e-6  # it acts
    data, _, _ = _refine.data_of(p, norm, pad=False)
    out = _refine.model(_refine.initial_params(cfg, w), _refine.structure(cfg), data)
    np.testing.assert_allclose(np.asarray(out), ref, rtol=0, atol=1e-12)
    back_cfg, back_w = _refine.to_config(cfg, _refine.initial_params(cfg, w))
    np.testing.assert_allclose(back_w, w, rtol=1e-12, atol=1e-15)
    assert back_cfg.keys() == cfg.keys()
    # Left out as record-specific, the model is the plain one.
    if name in RECORD_SPECIFIC:
        rest, w_rest = _model.without(cfg, [name], w)
        np.testing.assert_allclose(
            _model.predict(p, rest, w_rest, w_rest, norm),
            _model.predict(p, {}, w[: _basis.N_PLAYS + 1], w, norm),
            atol=1e-14,
        )


@pytest.mark.parametrize(
    "names",
    [
        ("minor_loop_noncongruence", "creep"),
        ("asymmetry", "linear_dynamics", "minor_loop_noncongruence"),
        ("delay", "minor_loop_noncongruence", "offset_drift"),
    ],
)
def test_play_terms_and_output_terms_keep_one_coefficient_order(names):
    # Play terms sit before every output term in the coefficient vector, whatever the effects'
    # ranks: the NumPy model, the JAX model and the round trip through the parameters agree.
    p = _record()
    cfg = {n: EFFECT[n].grid(p)[-1] for n in names}
    X = _model.linear_part(p, cfg)
    n_out = _model.output_terms(p, cfg, X[:, 0], (0.0, 1.0)).shape[1]
    w = _coefficients(cfg, n_out, np.random.default_rng(5))
    slices = _model.coefficient_slices(cfg)
    assert slices["minor_loop_noncongruence"].start == _basis.N_PLAYS + 1
    assert sorted(s.stop - s.start for s in slices.values()) == sorted(
        EFFECT[n].n_play_terms(cfg[n]) + EFFECT[n].n_columns(cfg[n]) for n in slices
    )
    norm = (0.05, 0.7)
    ref = _model.predict(p, cfg, w, w, norm)
    data, _, _ = _refine.data_of(p, norm, pad=False)
    out = _refine.model(_refine.initial_params(cfg, w), _refine.structure(cfg), data)
    np.testing.assert_allclose(np.asarray(out), ref, rtol=0, atol=1e-12)
    np.testing.assert_allclose(_refine.to_config(cfg, _refine.initial_params(cfg, w))[1], w, rtol=1e-12, atol=1e-15)
    # Leaving an effect out removes its own coefficients and nothing else.
    rest, w_rest = _model.without(cfg, ["minor_loop_noncongruence"], w)
    assert len(w_rest) == len(w) - EFFECT["minor_loop_noncongruence"].n_play_terms(cfg["minor_loop_noncongruence"])
    np.testing.assert_array_equal(w_rest[: _basis.N_PLAYS + 1], w[: _basis.N_PLAYS + 1])


@pytest.mark.parametrize("name", EFFECTS)
def test_each_effect_has_a_synthetic_form_that_changes_the_record(name):
    key = jax.random.PRNGKey(11)
    plain, _ = _hidden.generate((), key=key, n_samples=400, noise=1e-6)
    rec, truth = _hidden.generate((name,), key=key, n_samples=400, noise=1e-6)
    assert truth["effects"] == [name] and truth["forms"][name]
    np.testing.assert_array_equal(rec.u, plain.u)
    # The same PI and input: only the effect (and the output offset drawn after it) differ.
    d = (rec.y - rec.y.mean()) - (plain.y - plain.y.mean())
    assert np.std(d) > 1e-3 * np.ptp(plain.y)
