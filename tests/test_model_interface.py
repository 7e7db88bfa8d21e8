"""The one model interface: every model steps, runs, continues, inverts, saves and compares alike."""

import jax
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_creep import reference_lags
from test_fit import reference_pi

import piest_jax as pj
from piest_jax._models.model import run_steps

R, W = np.array([0.0, 0.5, 1.2]), np.array([1.0, 0.6, 0.4])
DT = 0.01


def models(method="auto"):
    pi = pj.PIOperator(R, W, 0.3, method=method)
    rng = np.random.default_rng(0)
    return {
        "pi": pj.HysteresisModel(pi, None, 0.2),
        "pi+creep": pj.HysteresisModel(pi, pj.Creep([0.1, 2.0], [0.5, 0.2], DT), 0.2),
        "gpi": pj.GeneralizedPI(pj.PIOperator(R, W, 0.2, method=method), [1.0, 0.5], [0.0, 1.0], [1.0, 2.0], 0.1),
        "preisach": pj.Preisach(R, np.linspace(-1, 3, 5), np.abs(rng.standard_normal((3, 5))), 0.1),
    }


def signal(T=1500):
    t = np.linspace(0, 15, T)
    return 1.0 + 2.0 * np.sin(t) * np.linspace(1.0, 0.3, T)


@pytest.mark.parametrize("name", list(models()))
def test_every_model_implements_the_interface(name):
    m = models()[name]
    assert isinstance(m, pj.AbstractHysteresisModel)
    u = signal()
    y = np.asarray(m(u))
    # Stepping sample by sample gives the run (to rounding: the kernel sums the plays its own way).
    np.testing.assert_allclose(np.asarray(run_steps(m, u)), y, rtol=0, atol=8 * np.finfo(float).eps * np.abs(y).max())
    # A run continued from its final state is the run.
    state = m.final_state(u[:600])
    np.testing.assert_array_equal(np.asarray(m(u[600:], state)), y[600:])
    # The inverse gives back an input whose output is the desired one.
    np.testing.assert_allclose(np.asarray(m(m.inverse(y))), y, atol=1e-10)


@pytest.mark.parametrize("name", ["pi", "pi+creep", "gpi"])
def test_steps_equal_the_scan_bit_for_bit(name):
    # With the plays run by the sequential scan, `step` is the run's own arithmetic.
    m = models("scan")[name]
    u = signal()
    np.testing.assert_array_equal(np.asarray(run_steps(m, u)), np.asarray(m(u)))


def test_state_of_pi_plus_creep_is_plays_and_lags():
    m = models()["pi+creep"]
    u = signal(400)
    x, z = m.init_state(u[0])
    np.testing.assert_array_equal(x, np.full(3, 0.3))
    np.testing.assert_array_equal(z, np.full(2, u[0]))  # lags at rest at the first input
    # Against NumPy references of the plays and the lags, from those states.
    ref = reference_pi(u, R, W, 0.3) + reference_lags(u, [0.1, 2.0], DT, u[0]) @ np.array([0.5, 0.2]) + 0.2
    np.testing.assert_allclose(np.asarray(run_steps(m, u)), ref, atol=1e-12)


@pytest.mark.parametrize("name", list(models()))
def test_saved_models_load_as_the_same_model_and_compare(tmp_path, name):
    m = models()[name]
    back = pj.load_model(pj.save_model(tmp_path / "m.json", m))
    assert type(back) is type(m)
    u = signal(500)
    np.testing.assert_array_equal(np.asarray(back(u)), np.asarray(m(u)))
    # Every model a file holds runs in `compare` (initial conditions estimated for PI models).
    y = np.asarray(m(u))
    got = pj.compare(back, u, y, estimate_initial=False)
    assert float(got.rmse) < 1e-12
    if isinstance(back, pj.HysteresisModel):
        assert float(pj.compare(back, u, y).rmse) < 1e-6
    else:
        with pytest.raises(ValueError, match="compare a .* with estimate_initial=False"):
            pj.compare(back, u, y)


def test_compare_takes_a_loaded_fit(tmp_path):
    # A newcomer's first call: the model file `piest fit` writes, checked on another run.
    u = signal(600)
    y = np.asarray(models()["pi"](u))
    fit = pj.fit_pi(u, y, 3, key=jax.random.key(0))
    back = pj.load_model(pj.save_model(tmp_path / "fit.json", fit))
    np.testing.assert_array_equal(
        np.asarray(pj.compare(back, u, y).prediction), np.asarray(pj.compare(fit, u, y).prediction)
    )


def test_a_model_without_inverse_says_so():
    class Scaled(pj.AbstractHysteresisModel):
        gain: float

        def init_state(self, u0):
            return None

        def step(self, state, u):
            return state, self.gain * u

        def with_state(self, state):
            return self

    m = Scaled(2.0)
    np.testing.assert_allclose(np.asarray(m(np.arange(4.0))), [0.0, 2.0, 4.0, 6.0])
    with pytest.raises(ValueError, match="a Scaled has no inverse"):
        m.inverse(np.zeros(3))


@settings(max_examples=25, deadline=None)
@given(
    st.lists(st.floats(0.05, 2.0), min_size=3, max_size=3),
    st.lists(st.floats(0.0, 1.0), min_size=2, max_size=2),
    st.integers(0, 2**31 - 1),
)
def test_pi_plus_creep_inverts_any_positive_model(w, c, seed):
    m = pj.HysteresisModel(pj.PIOperator(R, w, 0.0), pj.Creep([0.05, 1.0], c, DT), -0.4)
    yd = np.cumsum(np.random.default_rng(seed).standard_normal(300)) * 0.05
    u = m.inverse(yd)
    np.testing.assert_allclose(np.asarray(m(u)), yd, atol=1e-9)


def test_inverse_problems_are_named():
    pi = pj.PIOperator(R, W, 0.0)
    assert pj.HysteresisModel(pi, pj.Creep([0.1], [0.5], DT)).inverse_problem() is None
    # A relaxing creep whose steady gain outweighs the identity play: instantly invertible, but
    # the inverse drifts on slow targets.
    drifting = pj.HysteresisModel(pi, pj.Creep([5.0], [-2.0], DT))
    assert "steady gain" in drifting.inverse_problem()
    u = drifting.inverse(np.full(50, 0.3))  # it exists sample by sample
    np.testing.assert_allclose(np.asarray(drifting(u)), 0.3, atol=1e-9)
    signed = pj.HysteresisModel(pj.PIOperator(R, [1.0, -1.5, 0.2]))
    assert "at i = 2 they are -0.5" in signed.inverse_problem()
    assert "needs r_1 = 0" in pj.HysteresisModel(pj.PIOperator(R + 0.1, W)).inverse_problem()
    # The same reason the operator's inverse gives when it refuses.
    with pytest.raises(ValueError, match="at i = 2 they are -0.5"):
        signed.pi.inverse()
    assert "negative entries" in pj.Preisach(R, [0.0, 1.0], [[1.0, -0.1], [0.2, 0.3], [0.1, 0.1]]).inverse_problem()
    assert models()["gpi"].inverse_problem() is None
