"""The augmented PI model against plain NumPy references, effect by effect, and its fit."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from piest_jax import _effects
from piest_jax._effects import EFFECTS, N_PLAYS, ModelData

T = 512  # a padded length the diagnosis uses too, so compilations are shared
DT = 0.01
PERIOD = 0.05


def _data(u, y=None, rho=None):
    u = np.asarray(u, float)
    n = len(u)
    f = lambda a: jnp.asarray(a, jnp.float64)  # noqa: E731
    return ModelData(
        f(u), f(np.zeros(n) if y is None else y), f(np.zeros(n) if rho is None else rho),
        f(np.linspace(0, 1, n)), f(np.ones(n)), f(DT), f(DT), f(2 * np.pi * 5.0), f(PERIOD),
    )


def _u():
    t = np.arange(T) * DT
    return 0.9 * np.sin(2 * np.pi * 1.3 * t) * np.minimum(t / 0.5, 1) + 0.1 * np.sin(2 * np.pi * 4.1 * t)


def _theta(rng):
    th = _effects.initial_params()
    base = _effects._sl("base")
    th[base.start : base.start + N_PLAYS - 1] = rng.uniform(-2.5, -0.5, N_PLAYS - 1)
    th[base.start + N_PLAYS - 1 : base.stop - 1] = rng.uniform(0.05, 0.4, N_PLAYS)
    th[base.stop - 1] = 0.3
    return th


def _np_pi(g, r, w, x0, rt=None):
    x = np.array(x0, float)
    out = []
    for i, gi in enumerate(g):
        ri = r if rt is None else rt[i]
        x = np.maximum(gi - ri, np.minimum(gi + ri, x))
        out.append(x @ w)
    return np.array(out)


def _pred(th, names, data):
    return np.asarray(_effects.predict_jit(jnp.asarray(th), jnp.asarray(_effects.group_mask(names)), data))


@pytest.fixture
def setup(rng):
    u = _u()
    th = _theta(rng)
    r = np.asarray(_effects.thresholds_of(jnp.asarray(th)))
    w = np.asarray(_effects.weights_of(jnp.asarray(th)))
    return u, th, r, w, _np_pi(u, r, w, np.full(N_PLAYS, u[0])) + 0.3


def test_thresholds_start_at_zero_and_increase(rng):
    r = np.asarray(_effects.thresholds_of(jnp.asarray(_theta(rng))))
    assert r[0] == 0.0 and np.all(np.diff(r) > 0)


def test_base_model_is_the_pi_operator(setup):
    u, th, r, w, ref = setup
    # Effect parameters away from neutral must not matter while their groups are off.
    th2 = th.copy()
    th2[_effects._sl("base").stop :] = 0.37
    np.testing.assert_allclose(_pred(th2, [], _data(u)), ref, atol=1e-12)


def test_initial_state(setup):
    u, th, r, w, _ = setup
    dx = np.linspace(-0.3, 0.3, N_PLAYS)
    th[_effects._sl("initial_state")] = dx
    ref = _np_pi(u, r, w, u[0] + dx) + 0.3
    np.testing.assert_allclose(_pred(th, ["initial_state"], _data(u)), ref, atol=1e-12)


def test_integer_delay_shifts_the_output(setup):
    u, th, r, w, ref = setup
    th[_effects._sl("delay")] = np.log(np.expm1(3.0))  # softplus^-1(3): three samples
    out = _pred(th, ["delay"], _data(u))
    np.testing.assert_allclose(out[3:], ref[:-3], atol=1e-9)
    np.testing.assert_allclose(out[:3], ref[0], atol=1e-9)


def test_rate_dependent_thresholds(setup, rng):
    u, th, r, w, _ = setup
    rho = np.abs(np.gradient(u, DT))
    rho /= rho.max()
    th[_effects._sl("rate_dependence")] = [0.5, 0.05, np.log(0.5)]
    rp = (np.sqrt(rho + 1e-3) - np.sqrt(1e-3))[:, None]
    rt = np.maximum(r[None, :] * (1 + 0.5 * rp) + 0.05 * rp, 0)
    ref = _np_pi(u, r, w, np.full(N_PLAYS, u[0]), rt) + 0.3
    np.testing.assert_allclose(_pred(th, ["rate_dependence"], _data(u, rho=rho)), ref, atol=1e-12)


def test_asymmetry_polynomials(setup):
    u, th, r, w, _ = setup
    th[_effects._sl("asymmetry")] = [0.2, -0.1, 0.15, -0.05]
    g = u + 0.2 * u**2 - 0.1 * u**3
    z = _np_pi(g, r, w, np.full(N_PLAYS, g[0]))
    ref = z + 0.15 * z**2 - 0.05 * z**3 + 0.3
    np.testing.assert_allclose(_pred(th, ["asymmetry"], _data(u)), ref, atol=1e-12)


def test_offset_drift_is_a_cosine_series(setup):
    u, th, r, w, ref = setup
    d = np.array([0.1, -0.2, 0.05, 0.3])
    th[_effects._sl("offset_drift")] = d
    s = np.linspace(0, 1, T)
    drift = sum(d[k] * np.cos(np.pi * (k + 1) * s) for k in range(4))
    np.testing.assert_allclose(_pred(th, ["offset_drift"], _data(u)), ref + drift, atol=1e-12)


def test_creep_modes_are_first_order_lags(setup):
    u, th, r, w, ref = setup
    c = np.array([0.1, -0.05, 0.2, 0.03])
    th[_effects._sl("creep")] = np.r_[c, np.log(np.expm1(1.0))]  # scale 1 + softplus = 2
    z = ref - 0.3
    taus = PERIOD * 2.0 * np.asarray(_effects.CREEP_TAUS)
    out = z.copy()
    for ck, tau in zip(c, taus):
        a = np.exp(-DT / tau)
        s, lp = z[0], []
        for zi in z:
            s = a * s + (1 - a) * zi
            lp.append(s)
        out = out + ck * np.array(lp)
    np.testing.assert_allclose(_pred(th, ["creep"], _data(u)), out + 0.3, atol=1e-10)


@pytest.mark.parametrize("zeta", [0.3, 1.5])
def test_linear_dynamics_step_response(zeta):
    # A unit step through the plays (r_1 = 0 follows u exactly): the filter's step response.
    th = _effects.initial_params()
    base = _effects._sl("base")
    th[base.start + N_PLAYS - 1 : base.stop - 1] = 0.0
    th[base.start + N_PLAYS - 1] = 1.0
    th[base.stop - 1] = 0.0
    th[_effects._sl("linear_dynamics")] = [0.0, np.log(np.expm1(zeta))]
    n = T
    u = np.r_[0.0, np.ones(n - 1)]
    out = _pred(th, ["linear_dynamics"], _data(u))
    wn = 2 * np.pi * 5.0
    t = np.arange(n) * DT
    if zeta < 1:
        wd = wn * np.sqrt(1 - zeta**2)
        ref = 1 - np.exp(-zeta * wn * t) * (np.cos(wd * t) + zeta * wn / wd * np.sin(wd * t))
    else:
        p1, p2 = wn * (zeta - np.sqrt(zeta**2 - 1)), wn * (zeta + np.sqrt(zeta**2 - 1))
        ref = 1 - (p2 * np.exp(-p1 * t) - p1 * np.exp(-p2 * t)) / (p2 - p1)
    # The step enters as its average over the first interval (first-order hold): compare from the
    # second sample on with a tolerance of the response's change over half a step.
    np.testing.assert_allclose(out[-1], 1.0, atol=1e-6)
    half = np.max(np.abs(np.diff(ref)))
    assert np.max(np.abs(out[1:] - np.interp(t[1:] - DT / 2, t, ref))) < 0.5 * half + 1e-9


def test_jacobian_matches_finite_differences(setup):
    u, th, r, w, _ = setup
    th[_effects._sl("delay")] = np.log(np.expm1(1.4))
    th[_effects._sl("asymmetry")] = [0.1, 0.0, 0.1, 0.0]
    names = ["delay", "asymmetry", "linear_dynamics", "creep", "offset_drift"]
    g = jnp.asarray(_effects.group_mask(names))
    data = _data(u)
    f = lambda p: _effects.predict_jit(p, g, data)  # noqa: E731
    J = np.asarray(jax.jit(jax.jacfwd(_effects.predict))(jnp.asarray(th), g, data))
    idx = [0, N_PLAYS + 2, _effects._sl("delay").start, _effects._sl("linear_dynamics").start,
           _effects._sl("asymmetry").start + 2, _effects._sl("offset_drift").start]
    for i in idx:
        e = np.zeros_like(th)
        e[i] = 1e-6
        fd = (np.asarray(f(jnp.asarray(th + e))) - np.asarray(f(jnp.asarray(th - e)))) / 2e-6
        np.testing.assert_allclose(J[:, i], fd, atol=2e-5, rtol=1e-4)


def test_fit_recovers_noise_free_pi(setup, rng):
    u, th, r, w, ref = setup
    start = _effects.initial_params()
    start[_effects._sl("base").stop - 1] = 0.0
    data = _data(u, y=ref)
    res = _effects.fit(jnp.asarray(start), jnp.asarray(_effects.group_mask([])), data)
    pred = _pred(np.asarray(res.theta), [], data)
    assert np.sqrt(np.mean((pred - ref) ** 2)) < 1e-3 * np.ptp(ref)


def test_unknown_effect_names():
    with pytest.raises(ValueError, match="unknown effect 'hysteresis'"):
        _effects.group_mask(["hysteresis"])
    with pytest.raises(ValueError, match="unknown effect"):
        _effects.n_effect_params("creepy")
    assert [_effects.n_effect_params(e) for e in EFFECTS] == [N_PLAYS, 1, 2, 3, 5, 4, 4]
