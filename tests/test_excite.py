"""Input design (`design_input`, `piest excite`): the concave problem against a brute-force grid,
the realised input's constraints and event rows, its margin against the sine's and the
triangle's, the comparison's numbers against plain loops, and the command."""

import json
import math

import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from reference import play as ref_play

import piest_jax as pj
from piest_jax._cli import main
from piest_jax._excitation import design as D
from piest_jax._excitation.design_compare import time_to_error, worst_case_error

PAPER_R = np.array([0.0, 10 / 3, 20 / 3])


def _lam_min(shares, r, amplitude, step):
    gains, levels = D._gains(r, amplitude)
    return np.linalg.eigvalsh(D._information(np.asarray(shares), gains, D._costs(r, levels, step)))[0]


@pytest.mark.parametrize("r", [PAPER_R, np.array([0.0, 0.5, 3.0]), np.array([0.2, 1.0, 1.1])])
def test_optimal_shares_beat_every_point_of_a_grid(r):
    amplitude, step = 4.0 + r[-1], 0.05
    shares, value = D.optimal_shares(r, amplitude, step)
    assert np.all(shares >= 0) and math.isclose(shares.sum(), 1.0)
    assert math.isclose(value, _lam_min(shares, r, amplitude, step), rel_tol=1e-12)
    grid = [(a, b, 1 - a - b) for a in np.linspace(0, 1, 61) for b in np.linspace(0, 1, 61) if a + b <= 1]
    best = max(_lam_min(s, r, amplitude, step) for s in grid)
    # the grid's spacing 1/60 bounds how much better than its best the optimum can be
    assert best * (1 - 1e-6) <= value <= best * 1.1


def test_information_is_the_sum_of_each_levels_rows():
    r, amplitude, step = np.array([0.0, 1.0, 2.5]), 4.0, 0.1
    gains, levels = D._gains(r, amplitude)
    costs = D._costs(r, levels, step)
    shares = np.array([0.2, 0.3, 0.5])
    M = np.zeros((3, 3))
    for m in range(3):  # level m moves prefixes 0..m, prefix i over g_i
        for i in range(m + 1):
            p = (np.arange(3) <= i).astype(float)
            M += shares[m] / costs[m] * gains[i] ** 2 * np.outer(p, p)
    np.testing.assert_allclose(D._information(shares, gains, costs), M, rtol=1e-13)
    # a level's cost counts one segment per start, each at the slew limit (2 r_1 = 2 at 0.1: 20)
    np.testing.assert_array_equal(costs, [20, 50, 80])


thresholds = st.lists(st.floats(0.01, 3.0), min_size=1, max_size=5, unique=True).map(
    lambda x: np.concatenate([[0.0], np.cumsum(np.sort(x))])
)


@settings(max_examples=25, deadline=None)
@given(r=thresholds, extra=st.floats(0.05, 3.0), step=st.floats(0.02, 0.5))
def test_the_input_keeps_its_limits_and_moves_prefixes_only(r, extra, step):
    amplitude = float(r[-1] + extra)
    gains, levels = D._gains(r, amplitude)
    pairs = np.arange(1, r.size + 1) % 3  # every level, some twice, some not at all
    pairs[-1] = 1
    u, period = D._realise(r, pairs, levels, amplitude, step, 4000)
    assert np.all(np.abs(u) <= amplitude * (1 + 1e-12))
    assert np.all(np.abs(np.diff(u)) <= step * (1 + 1e-9))
    H = ref_play(u, r, np.zeros_like(r))
    head = D._travel([0.0, amplitude, -amplitude], step).size
    # after the first swing down, every play that moves moves with u: rows are prefixes of ones
    rho = np.diff(H[head - 1 :], axis=0) / np.where(np.diff(u[head - 1 :]) == 0, 1, np.diff(u[head - 1 :]))[:, None]
    moving = np.abs(rho) > 1e-9  # a play on a waypoint may move by a rounding error there
    np.testing.assert_allclose(rho[moving], 1.0, rtol=1e-9)
    assert np.all(np.diff(moving.astype(int), axis=1) <= 0)  # moving set = plays 0..i


def _margin(u, r, window):
    u = jnp.asarray(u)
    H = pj.play(u, jnp.asarray(r))
    return float(np.min(pj.pe_margin(H, u, jnp.asarray(r), window, stride=window // 10)))


@pytest.mark.parametrize("r", [PAPER_R, np.linspace(0, 8, 6), np.array([0, 0.1, 0.2, 1.0, 3.0, 3.2, 8.0])])
def test_design_beats_the_sine_and_the_triangle_of_the_same_slew(r):
    amplitude, dt, f, N, window = 10.0, 1e-3, 5.0, 3000, 600
    slew = 2 * np.pi * f * amplitude
    d = pj.design_input(r, amplitude=amplitude, n_samples=N, window=window, dt=dt, slew=slew)
    t = np.arange(N) * dt
    sine = amplitude * np.sin(2 * np.pi * f * t)
    # a triangle at the slew limit between the same extremes: full swings only
    tri = D._travel([0.0] + [amplitude * (-1) ** (k + 1) for k in range(40)], slew * dt)[:N]
    assert d.margin == pytest.approx(_margin(d.u, r, window), rel=1e-12)
    assert d.margin > 1.5 * _margin(sine, r, window)
    assert d.margin >= _margin(tri, r, window)


def test_design_refuses_what_it_cannot_do():
    kw = dict(amplitude=10.0, n_samples=1000, window=200, dt=1e-3, slew=600.0)
    with pytest.raises(ValueError, match="exceed the largest threshold"):
        pj.design_input([0, 10, 12], **kw)
    with pytest.raises(ValueError, match="longer than the window"):
        pj.design_input(PAPER_R, **(kw | {"window": 20}))
    with pytest.raises(ValueError, match="strictly increasing"):
        pj.design_input([0, 2, 1], **kw)
    with pytest.raises(ValueError, match="`slew`"):
        pj.design_input(PAPER_R, **(kw | {"slew": float("nan")}))


def test_time_to_error_and_worst_case_against_loops():
    err = np.array([1.0, 0.5, 0.005, 0.02, 0.009, 0.001])
    times = 0.1 * np.arange(1, 7)
    assert time_to_error(err, times) == pytest.approx(0.5)  # below for good from the 5th reading
    assert time_to_error(np.array([0.5, 0.02]), times[:2]) == math.inf
    assert time_to_error(np.array([0.001, 0.002]), times[:2]) == pytest.approx(0.1)
    rng = np.random.default_rng(0)
    H = np.cumsum(rng.normal(size=(103, 3)), axis=0)
    k, worst = worst_case_error(jnp.asarray(H), dt=0.01, P0=50.0, readings=10)
    Hs = H / np.abs(H).max()
    for kk, e in zip(k, worst):
        A = sum(0.01 / (1 + h @ h) ** 2 * np.outer(h, h) for h in Hs[:kk])
        assert e == pytest.approx(1 / (1 + 50.0 * np.linalg.eigvalsh(A)[0]), rel=1e-9)
    assert k[-1] == 103


def test_cli_excite(tmp_path, capsys):
    out = tmp_path / "design"
    code = main(
        ["excite", "--thresholds", "0,3.3333,6.6667", "--amplitude", "10", "--samples", "3000", "--out", str(out)]
    )
    assert code == 0
    rep = json.loads((out / "excite.json").read_text())
    assert rep["design"]["margin"] > rep["sine"]["margin"] > 0
    assert rep["margin_ratio"] == pytest.approx(rep["design"]["margin"] / rep["sine"]["margin"])
    assert rep["design"]["exact_condition_holds"] and rep["sine"]["exact_condition_holds"]
    # what the margin bounds, the worst weights' error, is smaller on the design
    assert rep["design"]["final_error_worst"] < rep["sine"]["final_error_worst"]
    t, u = np.loadtxt(out / "excite.csv", delimiter=",", skiprows=1, unpack=True)
    assert u.size == 3000 and np.max(np.abs(u)) <= 10 and np.max(np.abs(np.diff(u))) <= rep["slew"] * 1e-3 * (1 + 1e-9)
    assert (out / "excite.png").read_bytes()[:4] == b"\x89PNG"


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--thresholds", "0,1,2", "--amplitude", "1.5"], "--amplitude (1.5) must exceed"),
        (["--thresholds", "0,2,1"], "increase strictly"),
        (["--thresholds", "0,1", "--weights", "1,2,3"], "--weights has 3 values for 2"),
        (["--thresholds", "0,1", "--window", "5"], "longer than the window"),
        (["--thresholds", "0,1", "--frequency", "600"], "Nyquist"),
        (["--thresholds", "0"], "give --amplitude"),
        (["--thresholds", "0,1", "--amplitude", "1e300"], "--amplitude (1e+300) is too large"),
    ],
)
def test_cli_excite_errors(tmp_path, capsys, argv, message):
    assert main(["excite", "--samples", "500", "--out", str(tmp_path / "x"), *argv]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "x").exists()
