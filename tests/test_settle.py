"""Settling a Monte Carlo map in exact arithmetic: every verdict against the rational rank, the
draws it leaves to floating point, the band's rounding claim, and the CLI switch."""

import json
from fractions import Fraction

import jax
import numpy as np
import pytest
from reference import exact_play, exact_window_pe

import piest_jax as pj
from piest_jax._cli import main
from piest_jax._excitation import montecarlo as M
from piest_jax._excitation import settle as S
from piest_jax._excitation.draw import draw_case

pytestmark = pytest.mark.long

SETTINGS = dict(n_samples=300, n_plays=4, window=60, stride=15, dt=0.01)
N_DRAWS, SEED = 60, 5


@pytest.fixture(scope="module")
def settings():
    return pj.make_settings(**SETTINGS, dtype="float64", families=pj.INPUT_FAMILIES)


@pytest.fixture(scope="module")
def settled(settings):
    return pj.pe_map(jax.random.key(SEED), N_DRAWS, settings, settle=True, quiet=True)


@pytest.fixture(scope="module")
def truth(settings):
    """Each draw's PE verdict by rational elimination, on the floats the map's program drew."""
    fn, _ = M._engine(settings, tuple(jax.devices()), True)
    drawn = jax.device_get(fn(pj.draw_keys(jax.random.key(SEED), 0, N_DRAWS)))
    return np.array(
        [
            bool(
                np.all(
                    exact_window_pe(
                        drawn["u"][i], drawn["thresholds"][i], drawn["x0"][i], settings.window, settings.stride
                    )
                )
            )
            for i in range(N_DRAWS)
        ]
    )


def test_settled_verdicts_are_the_rational_rank_on_every_draw(settled, settings, truth):
    # Both kinds of draw are in the map, and most that are not PE needed settling.
    assert 0 < truth.sum() < N_DRAWS and settled.settled.sum() >= np.sum(~truth)
    np.testing.assert_array_equal(settled.pe, truth)
    np.testing.assert_array_equal(settled.exact, truth)
    report = pj.summarise(settled)
    assert report["exact_condition"]["violations"] == 0
    assert report["settling"]["done"] and report["settling"]["settled"] == settled.settled.sum()
    assert report["pe"] == truth.sum()


def test_unsettled_draws_are_above_the_band_with_agreeing_verdicts(settled, settings):
    band = pj.settle_band(settings.n_samples, settings.n_plays, settings.dtype)
    free = ~settled.settled
    assert free.any()
    assert np.all(settled.exact_level[free] >= band)
    raw = settled.c1_normalised > pj.numerical_tolerance("float64")
    np.testing.assert_array_equal(raw[free], settled.exact[free])
    np.testing.assert_array_equal(pj.needs_settling(settled), settled.settled)


def test_an_unsettled_map_keeps_the_float_verdicts(settled, settings):
    plain = pj.pe_map(jax.random.key(SEED), N_DRAWS, settings, quiet=True)
    assert plain.settled is None and not pj.summarise(plain)["settling"]["done"]
    np.testing.assert_array_equal(plain.pe, plain.c1_normalised > pj.numerical_tolerance("float64"))
    # Settling only ever changes the draws it settles.
    free = ~settled.settled
    np.testing.assert_array_equal(plain.pe[free], settled.pe[free])
    np.testing.assert_array_equal(plain.exact[free], settled.exact[free])


def test_settling_judges_the_floats_the_map_drew(settings):
    # The chunk hands its drawn inputs to the settling: they are the draws of the keys (up to
    # the last bits of the transcendental functions, which may differ between programs).
    fn, _ = M._engine(settings, tuple(jax.devices()[:1]), True)
    keys = pj.draw_keys(jax.random.key(SEED), 0, 20)
    out = jax.device_get(fn(keys))
    for i in range(20):
        u, r, x0, _ = draw_case(keys[i], int(pj.draw_family(i, settings)), settings.times(), 4)
        np.testing.assert_allclose(out["u"][i], u, rtol=0, atol=1e-12)
        np.testing.assert_allclose(out["thresholds"][i], r, rtol=1e-15)
        np.testing.assert_allclose(out["x0"][i], x0, rtol=0, atol=1e-12)
    settled = S.settle_draws(out, settings)
    assert "u" not in settled and "x0" not in settled and settled["settled"].any()


def _exact_event_level(u, r, x0, window):
    """The first window's event-matrix level from the event Gram built in exact arithmetic."""
    H = exact_play(u, r, x0)
    U = [Fraction(float(v)) for v in u]
    n = len(r)
    h0 = H[0]
    scale = max(abs(v) for v in h0)
    rows = [[v / scale for v in h0] if scale else list(h0)]
    for k in range(1, window):
        du = U[k] - U[k - 1]
        rows.append([(H[k][j] - H[k - 1][j]) / du if du else Fraction(0) for j in range(n)])
    G = np.array([[float(sum(row[i] * row[j] for row in rows)) for j in range(n)] for i in range(n)])
    lam = np.linalg.eigvalsh(G)
    return lam[0] / lam[-1]


@pytest.mark.parametrize("family", ["noise", "nested", "chirp"])
def test_settle_band_bounds_the_float_event_levels_rounding(family):
    # Long records with many fractional event entries (plays starting to move): the float64
    # level, built from running sums, is within the band of the level of the exact event Gram.
    T, n = 1200, 6
    t = np.arange(T) * 0.002
    band = pj.settle_band(T, n, "float64")
    for i in range(2):
        u, r, x0, _ = (np.asarray(a) for a in draw_case(jax.random.key(40 + i), family, t, n))
        H = pj.play(u, r, x0)
        got = float(pj.exact_condition(H, u, r, T).level[0])
        assert abs(got - _exact_event_level(u, r, x0, T)) <= band


def test_settle_band_values():
    eps = np.finfo(np.float64).eps
    assert pj.settle_band(5000, 10, "float64") == pytest.approx(2 * 10 * 5000**2 * eps)
    # Short records: never below the tolerance the float verdict itself uses.
    assert pj.settle_band(10, 2, "float64") == pj.numerical_tolerance("float64")


def test_cli_settle_writes_exact_verdicts(tmp_path, settled):
    out = tmp_path / "map"
    args = [
        "montecarlo",
        "--inputs",
        str(N_DRAWS),
        "--samples",
        "300",
        "--seed",
        str(SEED),
        "--plays",
        "4",
        "--window",
        "60",
        "--stride",
        "15",
        "--dt",
        "0.01",
        "--families",
        ",".join(pj.INPUT_FAMILIES),
        "--settle",
        "--quiet",
        "--out",
        str(out),
    ]
    assert main(args) == 0
    rep = json.loads((out / "pe_map.json").read_text())
    np.testing.assert_array_equal(rep["draws"]["pe"], settled.pe)
    np.testing.assert_array_equal(rep["draws"]["settled"], settled.settled)
    assert rep["settling"]["settled"] == int(settled.settled.sum())
    assert rep["exact_condition"]["violations"] == 0
