"""Inverse compensation: the feedforward input against a bisection reference, and the CLI."""

import json

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import piest_jax as pj
from piest_jax._cli import main

R = np.array([0.0, 0.4, 1.0, 1.7])
W = np.array([1.0, 0.5, 0.3, 0.2])
C = -0.25


def desired(T=300):
    t = np.linspace(0.0, 3.0, T)
    return t, 1.5 * np.sin(2 * np.pi * t) + 0.6 * np.sin(2 * np.pi * 2.7 * t)


def bisection_feedforward(r, w, c, x0, yd):
    """Independent reference: at each sample, the input whose one-step model output is yd_t.

    With positive cumulative weights the one-step output is increasing in u_t, so bisection finds
    the unique solution; the plays' states then advance with that input.
    """
    x = np.broadcast_to(np.asarray(x0, float), r.shape).copy()
    out = np.empty(len(yd))
    for t, target in enumerate(yd):

        def step(ut):
            return np.maximum(ut - r, np.minimum(ut + r, x))

        lo, hi = -100.0, 100.0
        for _ in range(200):
            mid = 0.5 * (lo + hi)
            if w @ step(mid) + c < target:
                lo = mid
            else:
                hi = mid
        out[t] = 0.5 * (lo + hi)
        x = step(out[t])
    return out


def test_feedforward_matches_bisection_reference():
    _, yd = desired()
    op = pj.PIOperator(R, W, 0.0)
    u = np.asarray(pj.feedforward(op, yd, offset=C))
    np.testing.assert_allclose(u, bisection_feedforward(R, W, C, 0.0, yd), atol=1e-9)
    np.testing.assert_allclose(op(u) + C, yd, atol=1e-10)


def test_fitted_model_uses_its_offset():
    t = np.linspace(0, 2, 400)
    u = 2.0 * np.sin(2 * np.pi * 2 * t)
    r = np.arange(4) / 4 * 0.5 * np.ptp(u)  # the grid uniform_pi uses for this input
    y = np.asarray(pj.PIOperator(r, W, u[0])(u)) + C
    fit = pj.uniform_pi(u, y, 4)
    np.testing.assert_allclose(fit.weights, W, rtol=1e-8)
    _, yd = desired()
    uff = pj.feedforward(fit, yd, initial_states=0.0)
    np.testing.assert_allclose(pj.PIOperator(r, W, 0.0)(uff) + C, yd, atol=1e-9)


def test_compensation_removes_error_with_and_without_model_error():
    _, yd = desired()
    op = pj.PIOperator(R, W, 0.0)
    exact = pj.evaluate_compensation(op, op, yd)
    assert float(exact.rmse_compensated) < 1e-10
    assert float(exact.rmse_linear) > 0.05
    # The plant differs from the model: thresholds 10 % larger and a mild output nonlinearity.
    plant_op = pj.PIOperator(1.1 * R, W, 0.0)

    def plant(u):
        y = plant_op(u)
        return y + 0.03 * y**2

    mismatch = pj.evaluate_compensation(plant, op, yd)
    assert float(mismatch.rmse_compensated) < 0.7 * float(mismatch.rmse_linear)
    # The linear feedforward is the least-squares line through (u_compensated, desired).
    a, b = np.polyfit(np.asarray(mismatch.u_compensated), yd, 1)
    np.testing.assert_allclose(mismatch.u_linear, (yd - b) / a, rtol=1e-8)


@given(st.lists(st.floats(-3, 3), min_size=4, max_size=4))
def test_admissible_states_property(x):
    xa = np.asarray(pj.admissible_states(R, np.asarray(x)))
    assert np.all(np.abs(np.diff(xa)) <= np.diff(R) + 1e-12)
    assert xa[0] == x[0]
    np.testing.assert_allclose(pj.admissible_states(R, xa), xa, atol=1e-12)


def test_not_invertible_model_is_rejected():
    _, yd = desired(20)
    with pytest.raises(ValueError, match="not invertible"):
        pj.feedforward(pj.PIOperator(R, [1.0, -2.0, 0.1, 0.1]), yd)
    # Huge but finite parameters: the inverse's would overflow; the message says so.
    with pytest.raises(ValueError, match="out of the range of float64: the inverse's thresholds"):
        pj.feedforward(pj.PIOperator([0.0, 1e300], [1e300, 1.0]), yd)
    with pytest.raises(ValueError, match="out of the range of float64: the inverse's weights"):
        pj.feedforward(pj.PIOperator([0.0, 1.0], [1e-300, 1e-300]), yd)
    with pytest.raises(ValueError, match="`model` must be a hysteresis model or a fit holding one, got str"):
        pj.feedforward("model", yd)
    with pytest.raises(ValueError, match="`desired` contains NaN"):
        pj.feedforward(pj.PIOperator(R, W), np.full(5, np.nan))


def write_model(path, weights=W):
    model = {"thresholds": R.tolist(), "weights": list(weights), "offset": C, "initial_states": [0.0] * 4}
    path.write_text(json.dumps(model))


def test_cli_compensate(tmp_path, capsys):
    t, yd = desired()
    write_model(tmp_path / "fit.json")
    np.savetxt(tmp_path / "d.csv", np.column_stack([t, yd]), delimiter=",", header="t,desired", comments="")
    rc = main(
        ["compensate", str(tmp_path / "fit.json"), str(tmp_path / "d.csv"), "--out", str(tmp_path / "out"), "--quiet"]
    )
    assert rc == 0
    assert len(capsys.readouterr().out.split()) == 3
    data = np.loadtxt(tmp_path / "out" / "compensate.csv", delimiter=",", skiprows=1)
    np.testing.assert_allclose(data[:, 2], bisection_feedforward(R, W, C, 0.0, yd), atol=1e-9)
    np.testing.assert_allclose(data[:, 3], yd, atol=1e-9)
    summary = json.loads((tmp_path / "out" / "compensate.json").read_text())
    assert summary["max_model_error"] < 1e-9


def test_cli_compensate_bad_input(tmp_path, capsys):
    t, yd = desired(10)
    write_model(tmp_path / "fit.json")
    np.savetxt(tmp_path / "d.csv", np.column_stack([t, yd]), delimiter=",", header="t,z", comments="")
    args = [str(tmp_path / "fit.json"), str(tmp_path / "d.csv"), "--out", str(tmp_path / "o")]
    assert main(["compensate", *args]) == 2
    assert "no column `y`" in capsys.readouterr().err
    (tmp_path / "bad.json").write_text('{"thresholds": [0, 1]}')
    assert main(["compensate", str(tmp_path / "bad.json"), *args[1:]]) == 2
    assert "missing weights" in capsys.readouterr().err
    write_model(tmp_path / "neg.json", weights=[1.0, -2.0, 0.1, 0.1])
    assert main(["compensate", str(tmp_path / "neg.json"), *args[1:], "--column", "z"]) == 2
    assert "not invertible" in capsys.readouterr().err
    write_model(tmp_path / "huge.json", weights=[1e-300, 1e-300, 1e-300, 1e-300])
    assert main(["compensate", str(tmp_path / "huge.json"), *args[1:], "--column", "z"]) == 2
    err = capsys.readouterr().err
    assert "out of the range of float64" in err and "NaN" not in err


def test_feedforward_with_a_creep_stronger_than_the_identity_play():
    """A creep that relaxes against the input by more than the identity play follows it (w_1 +
    Σ c_k < 0, as `piest fit` finds on the Aye record) leaves the static map non-monotone, so the
    rest input is found on its pieces; the model driven by the feedforward from rest tracks."""
    dt = 5e-3
    r = np.array([0.0, 0.3, 0.6])
    op = pj.PIOperator(r, np.array([0.5, 0.8, 0.7]), np.full(3, 1.0))
    creep = pj.Creep([0.05, 8.0], [4.0, -5.0], dt)  # present share 4(1 - e^-0.1) > 0, steady -1
    model = pj.HysteresisModel(op, creep, offset=0.2)
    t = np.arange(3000) * dt
    u = 1.0 + 0.8 * np.sin(2 * np.pi * 0.7 * t)
    target = np.asarray(model(u))
    ff = np.asarray(pj.feedforward(model, target))
    np.testing.assert_allclose(np.asarray(model(ff)), target, atol=1e-9)
    # the rest input reproduces the first target with the lags at rest there, by a plain loop
    x = np.clip(op.initial_states, ff[0] - r, ff[0] + r)
    assert float(np.dot(op.weights, x)) - 1.0 * ff[0] + 0.2 == pytest.approx(target[0], abs=1e-9)


def test_cli_notes_a_creep_whose_steady_gain_outweighs_the_first_play(tmp_path, capsys):
    op = pj.PIOperator(np.array([0.0, 0.3]), np.array([0.5, 0.8]), np.full(2, 1.0))
    pj.save_model(tmp_path / "m.json", pj.HysteresisModel(op, pj.Creep([0.05, 8.0], [4.0, -5.0], 5e-3)))
    t = np.arange(400) * 5e-3
    (tmp_path / "d.csv").write_text("t,desired\n" + "".join(f"{a},{np.sin(3 * a)}\n" for a in t))
    assert main(["compensate", str(tmp_path / "m.json"), str(tmp_path / "d.csv"), "--out", str(tmp_path / "o")]) == 0
    err = capsys.readouterr().err
    assert "the creep's steady gain (-1) outweighs the first play's weight (0.5)" in err
    rep = json.loads((tmp_path / "o" / "compensate.json").read_text())
    assert rep["max_model_error"] < 1e-9
