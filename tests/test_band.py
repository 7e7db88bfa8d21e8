"""Prediction bands: against finite-difference Jacobians of the NumPy reference model, the
closed-form regression band of a model linear in its parameters, and their coverage over noise
draws."""

import equinox as eqx
import numpy as np
import pytest
import reference as ref
from test_covariance import reference_model, signal

import piest_jax as pj

R, W, C = np.array([0.0, 0.4, 0.9]), np.array([1.0, 0.6, 0.5]), 0.3


def spd(p, seed):
    a = np.random.default_rng(seed).standard_normal((p, p))
    return a @ a.T / p + 0.1 * np.eye(p)


@pytest.mark.parametrize(
    "fit_states, lags, given", [(False, 0, False), (True, 0, False), (True, 2, False), (True, 2, True)]
)
def test_band_matches_finite_difference_jacobians(fit_states, lags, given):
    # A fitted model with a made-up covariance Σ, on a new input: sqrt(diag(J Σ Jᵀ)) with J by
    # central differences of the NumPy reference model over the named parameters.
    T, dt = 240, 0.01
    u = signal(T)
    y = ref.play(u, R, u[0]) @ W + C + 0.02 * np.random.default_rng(3).standard_normal(T)
    f = pj.fit_pi(u, y, 3, thresholds0=R, n_starts=1, n_lags=lags, dt=dt, fit_initial_states=fit_states, max_steps=20)
    names, theta = f.parameter_names, np.asarray(f.parameter_values)
    S = spd(len(names), 4)
    f = eqx.tree_at(lambda g: g.covariance, f, S)
    u2 = 0.8 * signal(150)[::-1] + 0.2
    x0 = np.asarray(f.initial_states)
    z0 = (
        np.full(lags, u2[0])
        if f.creep is None or f.creep.initial_states is None
        else np.asarray(f.creep.initial_states)
    )
    kwargs = {}
    if given:
        x0, z0 = np.array([u2[0], u2[0] + 0.1, u2[0] - 0.2]), np.array([0.1, -0.1])
        kwargs = dict(initial_states=x0, lag_states=z0)
    band = pj.prediction_band(f, u2, chunk=64, **kwargs)
    # The reference runs from the states used; given states are known, not parameters.
    free = [i for i, n in enumerate(names) if not (given and "initial_states" in n)]
    names_used, th, S = [names[i] for i in free], theta[free], S[np.ix_(free, free)]

    def model(v):
        return reference_model(u2, v, names_used, dt, x0, z0)

    np.testing.assert_allclose(band.prediction, model(th), atol=1e-10)
    np.testing.assert_allclose(band.prediction, f.model().with_initial_states(x0, z0 if lags else None)(u2), atol=1e-10)
    eps = 1e-6
    J = np.column_stack([(model(th + eps * e) - model(th - eps * e)) / (2 * eps) for e in np.eye(th.size)])
    np.testing.assert_allclose(band.std_error, np.sqrt(np.einsum("ti,ij,tj->t", J, S, J)), rtol=1e-5, atol=1e-8)
    np.testing.assert_allclose(
        band.measurement_std_error, np.sqrt(band.std_error**2 + float(f.residual_std) ** 2), rtol=1e-12
    )


def test_band_of_a_model_linear_in_its_parameters_is_the_regression_band():
    # Thresholds known (their covariance zero): y = [H(u), 1] β is linear in β = (weights,
    # offset), and the band at a new input's regressors x_t is the textbook sqrt(x_tᵀ σ²(AᵀA)⁻¹
    # x_t), A = [H, 1] on the fitted record, both built by the NumPy play loop.
    u = signal()
    y = ref.play(u, R, u[0]) @ W + C + 0.02 * np.random.default_rng(0).standard_normal(u.size)
    f = pj.fit_pi(u, y, 3, thresholds0=R, n_starts=1, covariance="gauss-newton")
    r = np.asarray(f.thresholds)
    A = np.column_stack([ref.play(u, r, u[0]), np.ones(u.size)])
    e = y - A @ np.asarray(f.parameter_values)[2:]
    np.testing.assert_allclose(float(f.residual_std), np.sqrt(e @ e / (u.size - 6)), rtol=1e-6)
    ols = float(f.residual_std) ** 2 * np.linalg.inv(A.T @ A)
    S = np.zeros((6, 6))
    S[2:, 2:] = ols
    f = eqx.tree_at(lambda g: g.covariance, f, S)
    u2 = 1.2 * np.sin(np.linspace(0.0, 9.0, 180)) + 0.1
    X = np.column_stack([ref.play(u2, r, 0.3), np.ones(u2.size)])
    band = pj.prediction_band(f, u2, initial_states=0.3)
    np.testing.assert_allclose(band.prediction, X @ np.asarray(f.parameter_values)[2:], atol=1e-10)
    np.testing.assert_allclose(band.std_error, np.sqrt(np.einsum("ti,ij,tj->t", X, ols, X)), rtol=1e-8)
    lo, hi = band.interval(0.95, measurement=False)
    np.testing.assert_allclose(hi - lo, 2 * 1.959963984540054 * band.std_error, rtol=1e-12)


def test_band_is_the_same_in_any_chunking():
    u = signal(200)
    y = ref.play(u, R, u[0]) @ W + C + 0.01 * np.sin(9 * u)
    f = pj.fit_pi(u, y, 3, thresholds0=R, n_starts=1, n_lags=1, dt=0.01, max_steps=20)
    whole = pj.prediction_band(f, u)
    for chunk in (1, 7, 64):
        part = pj.prediction_band(f, u, chunk=chunk)
        np.testing.assert_allclose(part.prediction, whole.prediction, atol=1e-12)
        np.testing.assert_allclose(part.std_error, whole.std_error, rtol=1e-10, atol=1e-14)


def test_bands_cover_at_their_level_over_noise_draws():
    # Known model, white noise: over the draws, the 95 % band of the mean prediction holds the
    # noiseless output, and the measurement band holds fresh noisy samples, at 90-98 % of samples.
    T, draws = 200, 100
    t = np.linspace(0.0, 2.0, T)
    u = 1.5 * np.sin(2 * np.pi * 2 * t) * (1 - 0.2 * t)
    y0 = ref.play(u, R, u[0]) @ W + C
    rng = np.random.default_rng(7)
    sd = 0.01 * np.ptp(y0)
    mean_cover, new_cover = [], []
    for _ in range(draws):
        f = pj.fit_pi(u, y0 + sd * rng.standard_normal(T), 3, thresholds0=R, n_starts=1)
        band = pj.prediction_band(f, u)
        mean_cover.append(band.coverage(y0, measurement=False))
        new_cover.append(band.coverage(y0 + sd * rng.standard_normal(T)))
    assert 0.90 <= np.mean(mean_cover) <= 0.98, np.mean(mean_cover)
    assert 0.90 <= np.mean(new_cover) <= 0.98, np.mean(new_cover)


def test_band_errors():
    u = signal(100)
    y = ref.play(u, R, u[0]) @ W
    f = pj.fit_pi(u, y + 0.01 * np.cos(7 * u), 3, thresholds0=R, n_starts=1, max_steps=5)
    with pytest.raises(ValueError, match="no covariance"):
        pj.prediction_band(pj.fit_pi(u, y, 2, n_starts=1, max_steps=5, covariance=None), u)
    with pytest.raises(ValueError, match="`initial_states` must be a scalar or have 3 entries"):
        pj.prediction_band(f, u, initial_states=np.zeros(2))
    with pytest.raises(ValueError, match="`lag_states` given, but the fit has no creep"):
        pj.prediction_band(f, u, lag_states=0.0)
    with pytest.raises(ValueError, match="`chunk` must be a positive whole number"):
        pj.prediction_band(f, u, chunk=0)
    with pytest.raises(ValueError, match="must be a PIFit"):
        pj.prediction_band(pj.uniform_pi(u, y, 2).model(), u)
    band = pj.prediction_band(f, u)
    with pytest.raises(ValueError, match="`level` must lie strictly between 0 and 1"):
        band.interval(1.0)
    with pytest.raises(ValueError, match="`y` has 99 samples but the band 100"):
        band.coverage(y[1:])
