"""Which way a loop runs, and a clockwise loop (an inverse PI's) fitted as what it is.

A PI operator with non-negative weights runs its loop counterclockwise; its inverse runs it
clockwise, which non-negative weights can only fit with a straight line. `loop_direction` tells
them apart from the signed area (against a plain loop over the samples), and `identify` / `piest
fit` then fit a clockwise loop with signed weights and say so, as `diagnose` does with its models.
"""

import dataclasses
import json

import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import piest_jax as pj
from piest_jax._diagnosis import model
from piest_jax._diagnosis.scaling import prepared, scaling_of

DT = 0.01
T = 1500


def _input(rng_phase=0.0):
    t = np.arange(T) * DT
    return t, 3.0 * np.sin(2 * np.pi * 0.5 * t + rng_phase) * (1 + 0.3 * np.sin(2 * np.pi * 0.07 * t))


def _operator():
    return pj.PIOperator(jnp.array([0.0, 0.5, 1.0, 1.5]), jnp.array([1.0, 0.5, 0.3, 0.2]))


def _area_loop(u, y):
    """The signed area of y against u by a plain loop, on the residual of the least-squares line."""
    n = len(u)
    su, sy = sum(u), sum(y)
    suu = sum(a * a for a in u)
    suy = sum(a * b for a, b in zip(u, y))
    b = (n * suy - su * sy) / (n * suu - su * su)
    a = (sy - b * su) / n
    e = [yi - (a + b * ui) for ui, yi in zip(u, y)]
    area = 0.0
    for k in range(1, n):
        area += 0.5 * (e[k] + e[k - 1]) * (u[k] - u[k - 1])
    mean = sum(e) / n
    sd = (sum((x - mean) ** 2 for x in e) / n) ** 0.5
    steps = sum((u[k] - u[k - 1]) ** 2 for k in range(1, n)) ** 0.5
    return area / (sd * steps)


def test_a_pi_runs_counterclockwise_and_its_inverse_clockwise():
    rng = np.random.default_rng(0)
    _, u = _input()
    op = _operator()
    forward = np.asarray(op(jnp.asarray(u))) + 0.01 * rng.normal(size=T)
    inverse = np.asarray(op.inverse()(jnp.asarray(u))) + 0.01 * rng.normal(size=T)
    a, b = pj.loop_direction(u, forward), pj.loop_direction(u, inverse)
    assert a.direction == "counterclockwise" and a.score < -20
    assert b.direction == "clockwise" and b.score > 20
    assert a.score == pytest.approx(_area_loop(list(u), list(forward)), rel=1e-9)
    assert b.score == pytest.approx(_area_loop(list(u), list(inverse)), rel=1e-9)
    assert b.to_json() == {"direction": "clockwise", "score": b.score}


@given(st.integers(0, 2**32 - 1), st.floats(-3.0, 3.0), st.floats(-5.0, 5.0))
def test_a_line_with_noise_has_no_loop(seed, slope, intercept):
    # White noise on a straight line of the input: the score is about N(0, 1), far from the bar.
    rng = np.random.default_rng(seed)
    _, u = _input(rng.uniform(0, 2 * np.pi))
    y = intercept + slope * u + 0.05 * rng.normal(size=T)
    d = pj.loop_direction(u, y)
    assert d.direction == "none" and abs(d.score) < 5.0
    # An exact line has no residual at all.
    assert pj.loop_direction(u, intercept + slope * u).direction == "none"


def test_loop_direction_refuses_bad_data():
    with pytest.raises(ValueError, match="samples but `y` has"):
        pj.loop_direction(np.arange(5.0), np.arange(4.0))
    with pytest.raises(ValueError, match="at least 3 samples"):
        pj.loop_direction(np.arange(2.0), np.arange(2.0))
    with pytest.raises(ValueError, match="NaN or inf"):
        pj.loop_direction(np.array([0.0, 1.0, np.nan]), np.arange(3.0))


@pytest.fixture(scope="module")
def clockwise_record():
    rng = np.random.default_rng(1)
    t, u = _input()
    y = np.asarray(_operator().inverse()(jnp.asarray(u))) + 0.01 * rng.normal(size=T)
    return pj.Record.from_arrays(t, u, y, source="inverse-pi")


def test_identify_fits_a_clockwise_loop_with_signed_weights(clockwise_record):
    rec = clockwise_record
    got = pj.identify(rec, model="pi", plays=4)
    assert got.loop.direction == "clockwise" and not got.positive_weights
    # The inverse of a PI is a PI with signed weights: the fit reaches the noise (0.01), where
    # non-negative weights can only draw a line through the loop.
    forced = pj.identify(rec, model="pi", plays=4, positive_weights=True)
    assert forced.loop.direction == "clockwise" and forced.positive_weights
    assert float(got.fit.rmse) < 0.015
    assert float(forced.fit.rmse) > 4 * float(got.fit.rmse)
    assert np.any(np.asarray(got.fit.weights) < 0)
    report = got.to_json()
    assert report["loop"]["direction"] == "clockwise" and report["positive_weights"] is False


def test_piest_fit_says_a_loop_runs_clockwise(clockwise_record, tmp_path, capsys):
    rec = clockwise_record
    data = tmp_path / "inverse.csv"
    np.savetxt(data, np.column_stack([rec.t, rec.u, rec.y]), delimiter=",", header="t,u,y", comments="")
    code = pj.run_cli(["fit", str(data), "--model", "pi", "--plays", "4", "--out", str(tmp_path / "f"), "--quiet"])
    err = capsys.readouterr().err
    assert code == 0, err
    assert "note: the loop runs clockwise (the output leads the input" in err
    assert "fitted with signed weights" in err
    report = json.loads((tmp_path / "f" / "fit.json").read_text())
    assert report["loop"]["direction"] == "clockwise" and report["positive_weights"] is False
    assert report["rmse"] < 0.015


def test_diagnose_fits_a_clockwise_loop_with_signed_play_weights(clockwise_record):
    # The inverse of a PI is a PI with signed weights: the diagnosis's plain model reaches the
    # noise (0.01) with them, and nothing is left for an effect to explain.
    d = pj.diagnose(clockwise_record)
    assert d.loop.direction == "clockwise"
    assert d.effects == [], d.candidates
    assert d.baseline_rmse < 0.015 and d.final_rmse < 0.015
    # The operator itself runs counterclockwise: its diagnosis keeps the non-negative plays of
    # the physical model, and fitting the inverse's record with them leaves a line's error.
    rec = clockwise_record
    forward = pj.Record.from_arrays(rec.t, rec.u, np.asarray(_operator()(jnp.asarray(rec.u))), source="pi")
    assert not scaling_of(forward).signed_plays and scaling_of(rec).signed_plays
    sc = dataclasses.replace(scaling_of(rec), signed_plays=False)
    p = prepared(rec, sc)
    f = model.fit(p, {})
    assert np.all(f.w[: model.N_PLAYS] >= 0)
    assert np.sqrt(np.mean((f.A @ f.w - p.y) ** 2)) * sc.y_half > 4 * d.baseline_rmse


def test_piest_diagnose_says_a_loop_runs_clockwise(clockwise_record, tmp_path, capsys):
    rec = clockwise_record
    data = tmp_path / "inverse.csv"
    np.savetxt(data, np.column_stack([rec.t, rec.u, rec.y]), delimiter=",", header="t,u,y", comments="")
    out = tmp_path / "d"
    argv = ["diagnose", str(data), "--max-effects", "1", "--candidates", "delay", "--solver", "none"]
    code = pj.run_cli([*argv, "--out", str(out), "--quiet"])
    err = capsys.readouterr().err
    assert code == 0, err
    assert "note: the loop runs clockwise" in err and "fitted with signed weights" in err
    report = json.loads((out / "report.json").read_text())
    assert report["loop"]["direction"] == "clockwise" and report["loop"]["score"] > 20
    assert report["baseline_rmse"] < 0.015, report["baseline_rmse"]
    assert "**The loop runs clockwise**" in (out / "report.md").read_text()
