"""The diagnosis model in JAX and its joint optimistix refinement.

The NumPy/SciPy regressors of `_effects` (scipy's first-order-hold discretisation and lfilter,
NumPy play loops) are the independent reference for the JAX model.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from piest_jax._diagnosis import basis as _basis
from piest_jax._diagnosis import model as _model
from piest_jax._diagnosis import refine as _refine
from piest_jax._diagnosis.effects.creep import Lags
from piest_jax._diagnosis.scaling import Prepared

T = 1200
DT = 1e-3


def _record(y=None):
    t = np.arange(T) * DT
    u = 0.9 * np.sin(2 * np.pi * 3 * t) * np.exp(-t / 2) + 0.1 * np.sin(2 * np.pi * 11 * t)
    return Prepared(u, np.zeros(T) if y is None else y, t, rate_scale=20.0, period=0.33)


def _coefficients(p, cfg, rng):
    X = _model.linear_part(p, cfg)
    n_out = _model.output_terms(p, cfg, X[:, 0], (0.0, 1.0)).shape[1]
    w = np.concatenate([rng.uniform(0.2, 1.0, _basis.N_PLAYS) / 8, [0.1], rng.normal(0, 0.1, n_out)])
    if "creep" in cfg and cfg["creep"].drive == "output":  # its coefficients are kept >= 0
        sl = _model.output_slices(cfg)["creep"]
        w[sl] = np.abs(w[sl])
    return w


CONFIGS = [
    {},
    {"delay": 0.0037},
    {"linear_dynamics": ("first", 0.004)},
    {"linear_dynamics": ("second", 300.0, 0.3)},
    {"rate_dependence": ("scale", 0.5, 1.0)},
    {"rate_dependence": ("add", 0.05, 0.5)},
    {"asymmetry": 0.2},
    {"saturation": (1.8, 0.15)},
    {"asymmetry": -0.2, "saturation": (1.0, 0.0)},
    {"saturation": (0.0, 0.0), "creep": Lags((0.1, 1.0), "output")},
    {"creep": Lags((0.05, 0.3, 1.0), "output")},
    {"creep": Lags((0.05, 0.3, 1.0), "input", 0.02)},
    {"asymmetry": None, "saturation": (0.0, 0.0), "creep": Lags((0.1, 1.0), "input", 0.05)},
    {"offset_drift": True},
    {"initial_state": (0.7, -0.3)},
    {"delay": 0.002, "asymmetry": -0.2, "creep": Lags((0.1, 1.0), "output"), "offset_drift": True},
    {"delay": 0.002, "asymmetry": -0.2, "creep": Lags((0.1, 1.0), "input", 0.05), "offset_drift": True},
]


@pytest.mark.parametrize("cfg", CONFIGS, ids=lambda c: "+".join(c) or "plain")
def test_model_matches_the_numpy_regressors(cfg):
    p = _record()
    w = _coefficients(p, cfg, np.random.default_rng(len(cfg)))
    norm = (0.05, 0.7)
    # With the creep driven by the current coefficients, `_model.predict` is the exact model.
    ref = _model.predict(p, cfg, w, w, norm)
    data, _, _ = _refine.data_of(p, norm, pad=False)
    out = _refine.model(_refine.initial_params(cfg, w), _refine.structure(cfg), data)
    np.testing.assert_allclose(np.asarray(out), ref, rtol=0, atol=1e-12)
    back_cfg, back_w = _refine.to_config(cfg, _refine.initial_params(cfg, w))
    np.testing.assert_allclose(back_w, w, rtol=1e-12, atol=1e-15)
    assert set(back_cfg) == set(cfg)


def test_transferable_model_drops_history_and_drift():
    cfg = {"initial_state": (0.7, -0.3), "offset_drift": True}
    p = _record()
    w = _coefficients(p, cfg, np.random.default_rng(3))
    data, _, _ = _refine.data_of(p, (0.0, 1.0), pad=False)
    out = _refine.model(_refine.initial_params(cfg, w), _refine.structure(cfg), data, transferable_only=True)
    plain = _model.predict(p, {}, w[: _basis.N_PLAYS + 1], w, (0.0, 1.0))
    np.testing.assert_allclose(np.asarray(out), plain, atol=1e-12)


def test_gradient_matches_finite_differences():
    cfg = {"delay": 0.0037, "linear_dynamics": ("second", 300.0, 0.3), "rate_dependence": ("scale", 0.5, 1.0)}
    p = _record()
    w = _coefficients(p, cfg, np.random.default_rng(5))
    y = _model.predict(p, cfg, w, w, (0.0, 1.0)) + 0.01 * np.sin(np.arange(T))
    st = _refine.structure(cfg)
    data, yy, mask = _refine.data_of(_record(y), (0.0, 1.0))
    theta = _refine.initial_params({**cfg, "delay": 0.0031}, w)

    def loss(th):
        return jnp.sum(_refine._residuals(th, (st, data, yy, mask)) ** 2)

    g = jax.grad(loss)(theta)
    for name in ("log_delay", "log_dynamics", "log_rate", "weights"):
        v = np.asarray(theta[name], float)
        for i in range(min(v.size, 3)):
            e = np.zeros(v.size)
            e[i] = 1e-6
            plus = {**theta, name: jnp.asarray((v.ravel() + e).reshape(v.shape))}
            minus = {**theta, name: jnp.asarray((v.ravel() - e).reshape(v.shape))}
            fd = (float(loss(plus)) - float(loss(minus))) / 2e-6
            assert np.isclose(float(np.ravel(g[name])[i]), fd, rtol=1e-4, atol=1e-10), (name, i)


@pytest.mark.parametrize(
    "true, start",
    [
        ({"delay": 0.0037, "asymmetry": 0.2}, {"delay": 0.0043, "asymmetry": 0.26}),
        ({"linear_dynamics": ("second", 300.0, 0.3)}, {"linear_dynamics": ("second", 340.0, 0.36)}),
        (
            {"rate_dependence": ("scale", 0.5, 1.0), "initial_state": (0.7, -0.3)},
            {"rate_dependence": ("scale", 0.62, 0.85), "initial_state": (0.6, -0.25)},
        ),
    ],
    ids=["delay+asymmetry", "second_order", "rate+initial_state"],
)
def test_refinement_recovers_parameters_off_the_grid(true, start):
    p0 = _record()
    w = _coefficients(p0, true, np.random.default_rng(11))
    # The output polynomial's powers are taken about the centre of the hysteresis output.
    norm = _model._centre(_model.linear_part(p0, true) @ w[: _basis.N_PLAYS + 1])
    p = _record(_model.predict(p0, true, w, w, norm))
    f = _model.fit(p, start)
    # Noise-free data: stop on the error's own scale, not on a measured record's noise level.
    r = _refine.refine(p, start, f.w, f.norm, rtol=1e-10, atol=1e-16, max_steps=300)
    assert r.accepted and r.result == "successful", r
    assert r.rmse < 1e-9 < r.rmse_start, r
    for k, v in true.items():
        got = r.cfg[k]
        want = np.atleast_1d(np.asarray(v if not isinstance(v, tuple) or not isinstance(v[0], str) else v[1:], float))
        plain = not isinstance(got, tuple) or not isinstance(got[0], str)
        have = np.atleast_1d(np.asarray(got if plain else got[1:], float))
        np.testing.assert_allclose(have, want, rtol=1e-8, err_msg=k)
    if "asymmetry" in true:  # the centre moved from the fit's to the true one
        assert abs(f.norm[0] - norm[0]) > 1e-3
        np.testing.assert_allclose(float(r.theta["poly_centre"]), norm[0], rtol=1e-8)


def test_unknown_solver_is_refused():
    p = _record(np.sin(np.arange(T) * 0.01))
    f = _model.fit(p, {})
    with pytest.raises(ValueError, match="unknown solver 'newton'"):
        _refine.refine(p, {}, f.w, f.norm, solver="newton")
