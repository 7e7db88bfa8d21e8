"""Convergence certificate, closed-form information solution and noise covariance vs NumPy loops."""

import numpy as np
import pytest

import piest_jax as pj
from piest_jax._estimation.certificate import noise_covariance
from piest_jax._estimation.reproduce import CASES, THRESHOLDS

DT = 1e-3
P_MATRIX = np.array([[2e6, 1e5, 0.0], [1e5, 5e5, -2e4], [0.0, -2e4, 1e6]])


def _case(name, n_samples=None):
    case = CASES[name]
    u = case.input()[:n_samples]
    op = pj.PIOperator(THRESHOLDS, case.weights)
    return np.asarray(op.regressor(u)), np.asarray(op(u)), np.asarray(case.weights)


FIG5 = _case("fig5")
FIG6 = _case("fig6", 400)


def _m2(h, normalisation):
    return (1 + h @ h) ** 2 if normalisation == "paper" else 1 + h @ h


def _p0(P0):
    return P0 * np.eye(3) if np.ndim(P0) == 0 else np.asarray(P0)


def _error_closed_form(H, P0, w_err0, normalisation):
    """W̃_k = R_k⁻¹ P0⁻¹ W̃_0 with R_k = P0⁻¹ + Σ dt h hᵀ / m², accumulated sample by sample."""
    R0 = np.linalg.inv(_p0(P0))
    R, out = R0.copy(), []
    for h in H:
        R += DT / _m2(h, normalisation) * np.outer(h, h)
        out.append(np.linalg.solve(R, R0 @ w_err0))
    return np.array(out)


@pytest.mark.parametrize("P0", [1e2, 1e8, "matrix"])
@pytest.mark.parametrize("normalisation", ["paper", "standard"])
def test_noise_free_error_equals_closed_form(P0, normalisation):
    H, y, w_true = FIG6
    P0 = P_MATRIX if P0 == "matrix" else P0
    w0 = np.array([0.5, -1.0, 2.0])
    est = pj.estimate(pj.ContinuousRLS(P0, DT, normalisation=normalisation), H, y, w0)
    ref = _error_closed_form(H, P0, w0 - w_true, normalisation)
    scale = np.linalg.norm(w0 - w_true)
    np.testing.assert_allclose(np.asarray(est.weights) - w_true, ref, rtol=0, atol=1e-9 * scale)


@pytest.mark.parametrize(
    "P0,normalisation,case",
    [(1e5, "paper", "fig5"), (1e8, "paper", "fig5"), (1e4, "standard", "fig5"), ("matrix", "paper", "fig6")],
)
def test_error_stays_inside_the_certificate(P0, normalisation, case):
    H, y, w_true = FIG5 if case == "fig5" else FIG6
    P0 = P_MATRIX if P0 == "matrix" else P0
    cert = pj.convergence_certificate(H, P0, DT, 200, normalisation=normalisation)
    gram, pe = np.asarray(cert.gram_bound), np.asarray(cert.pe_bound)
    assert np.all(gram <= pe * (1 + 1e-12))
    for w0 in (np.zeros(3), np.array([4.0, -2.0, 0.5]), w_true + np.array([0.0, 0.0, 3.0])):
        est = pj.estimate(pj.ContinuousRLS(P0, DT, normalisation=normalisation), H, y, w0)
        rel = np.linalg.norm(np.asarray(est.weights) - w_true, axis=1) / np.linalg.norm(w0 - w_true)
        assert np.all(rel <= gram * (1 + 1e-8))
    if case == "fig5":
        assert pe[-1] < 1.0  # the PE level alone already certifies convergence on the record


def test_certificate_is_tight_along_the_least_excited_direction():
    H, y, w_true = FIG5
    P0 = 1e6
    A = sum(DT / _m2(h, "paper") * np.outer(h, h) for h in H)
    lam, vec = np.linalg.eigh(A)
    cert = pj.convergence_certificate(H, P0, DT, 200)
    est = pj.estimate(pj.ContinuousRLS(P0, DT), H, y, w_true + vec[:, 0])
    rel = np.linalg.norm(np.asarray(est.weights[-1]) - w_true)
    np.testing.assert_allclose(rel, 1 / (1 + P0 * lam[0]), rtol=1e-6)
    np.testing.assert_allclose(float(cert.gram_bound[-1]), 1 / (1 + P0 * lam[0]), rtol=1e-6)


def test_pe_bound_matches_its_definition():
    H, _, _ = FIG5
    cert = pj.convergence_certificate(H, 1e6, DT, 250)
    c1 = min(np.linalg.eigvalsh(H[s : s + 250].T @ H[s : s + 250] / 250)[0] for s in range(752))
    m2 = max(_m2(h, "paper") for h in H)
    k = np.arange(len(H))
    expected = 1 / (1 + 1e6 * ((k + 1) // 250) * 250 * DT * c1 / m2)
    np.testing.assert_allclose(float(cert.c1), c1, rtol=1e-9)
    np.testing.assert_allclose(float(cert.max_m2), m2, rtol=1e-12)
    np.testing.assert_allclose(cert.pe_bound, expected, rtol=1e-9)


def test_no_pe_no_certified_progress_and_no_blow_up():
    t = np.arange(1001) * DT
    u = 2.0 * np.sin(2 * np.pi * 5 * t)  # below r_2: plays 2 and 3 stay at 0
    op = pj.PIOperator(THRESHOLDS, (1.0, 3.0, 5.0))
    H, y = np.asarray(op.regressor(u)), np.asarray(op(u))
    cert = pj.convergence_certificate(H, 1e12, DT, 200)
    assert abs(float(cert.c1)) < 1e-12
    np.testing.assert_allclose(cert.pe_bound, 1.0)
    np.testing.assert_allclose(cert.gram_bound, 1.0, rtol=1e-9)
    est = pj.estimate(pj.ContinuousRLS(1e12, DT), H, y)
    rel = np.linalg.norm(np.asarray(est.weights) - [1, 3, 5], axis=1) / np.linalg.norm([1, 3, 5])
    assert np.all(np.isfinite(rel)) and np.all(rel <= 1 + 1e-9)


def test_information_form_matches_numpy_solve():
    H, y, _ = FIG6
    w0 = np.array([1.0, 0.0, -1.0])
    got = np.asarray(pj.information_form(H, y, P_MATRIX, DT, initial_weights=w0))
    R0 = np.linalg.inv(P_MATRIX)
    R, b = R0.copy(), R0 @ w0
    for k, (h, yk) in enumerate(zip(H, y)):
        c = DT / _m2(h, "paper")
        R += c * np.outer(h, h)
        b += c * h * yk
        if k % 50 == 0 or k == len(H) - 1:
            np.testing.assert_allclose(got[k], np.linalg.solve(R, b), rtol=1e-8, atol=1e-10)


@pytest.mark.parametrize("normalisation", ["paper", "standard"])
def test_noise_covariance_matches_numpy(normalisation):
    H, _, _ = FIG6
    R = np.linalg.inv(P_MATRIX)
    Q = np.zeros((3, 3))
    for h in H:
        c = DT / _m2(h, normalisation)
        R = R + c * np.outer(h, h)
        Q = Q + c**2 * np.outer(h, h)
    ref = 0.3**2 * np.linalg.inv(R) @ Q @ np.linalg.inv(R)
    got = np.asarray(noise_covariance(H, P_MATRIX, DT, 0.3, normalisation=normalisation))
    np.testing.assert_allclose(got, ref, rtol=1e-8, atol=1e-12 * np.abs(ref).max())


def test_errors():
    H, y, _ = FIG6
    with pytest.raises(ValueError, match="between 1 and the signal length"):
        pj.convergence_certificate(H, 1e6, DT, 5000)
    with pytest.raises(ValueError, match="must be positive definite"):
        pj.convergence_certificate(H, -1.0, DT, 100)
    with pytest.raises(ValueError, match=r"`P0` is \(2, 2\) but the regressor `H` has 3 columns"):
        pj.convergence_certificate(H, np.eye(2), DT, 100)
    with pytest.raises(ValueError, match="`dt` must be positive"):
        pj.convergence_certificate(H, 1e6, -DT, 100)
    with pytest.raises(ValueError, match="unknown normalisation"):
        pj.information_form(H, y, 1e6, DT, normalisation="other")
    with pytest.raises(ValueError, match="`y` has 10 samples"):
        pj.information_form(H, y[:10], 1e6, DT)
    with pytest.raises(ValueError, match="`y` contains NaN or inf"):
        pj.information_form(H, np.where(np.arange(len(y)) == 3, np.nan, y), 1e6, DT)
    with pytest.raises(ValueError, match="`initial_weights` has shape"):
        pj.information_form(H, y, 1e6, DT, initial_weights=np.zeros(2))
    with pytest.raises(ValueError, match="`noise_std` must be non-negative"):
        noise_covariance(H, 1e6, DT, -0.1)
