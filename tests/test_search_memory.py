"""The diagnosis search remembers what it computed on a record (`Prepared.cache`): a configuration
scored once is not fitted again, creep's lags of the input are filtered once, and the answers are
those of a search that recomputes everything."""

import collections

import jax
import numpy as np
import pytest

import piest_jax as pj
from piest_jax._diagnosis import diagnose as _diagnose
from piest_jax._diagnosis import hidden as _hidden
from piest_jax._diagnosis.effects import EFFECT
from piest_jax._diagnosis.effects import creep as _creep
from piest_jax._diagnosis.effects.creep import Lags


def test_keys_tell_apart_what_the_fits_tell_apart():
    frozen = _diagnose._frozen
    assert frozen(Lags((1.0, 10.0), "input", 0.1)) == frozen(Lags((1.0, 10.0), "input", 0.1))
    assert frozen(Lags((1.0, 10.0), "input", 0.1)) != frozen(Lags((1.0, 10.0), "input", 0.2))
    assert frozen(Lags((1.0, 10.0), "input")) != frozen(Lags((1.0, 10.0), "output"))
    assert frozen(Lags((1.0, 10.0), "input")) != frozen((1.0, 10.0))
    assert frozen(0.0) != frozen(-0.0)
    assert frozen(0.1) != frozen(np.nextafter(0.1, 1.0))
    assert frozen(("first", 0.5)) != frozen(("second", 0.5))
    assert frozen({"delay": 0.01, "creep": Lags((2.0,), "input")}) == frozen(
        {"creep": Lags((2.0,), "input"), "delay": 0.01}
    )
    assert frozen({"delay": 0.01}) != frozen({"delay": 0.02})
    assert frozen([None, "eight_bands"]) != frozen([None, "four_bands"])


@pytest.fixture(scope="module")
def pair_record():
    # Saturation and creep at once: the second round revisits the first effect, and pruning
    # revisits each named one, so the search asks for some additions more than once.
    cls = ("saturation", "creep")
    return _hidden.generate(cls, key=pj.hidden_effect_key(jax.random.PRNGKey(7), cls, 0), n_samples=400)[0]


CANDIDATES = ["saturation", "creep", "delay", "offset_drift"]


def _summary(s):
    return s["effects"], s["pruned"], s["heldout_rmse_final"], [r["candidates"] for r in s["rounds"]]


def test_a_search_fits_each_addition_once_and_answers_as_without_memory(pair_record, monkeypatch):
    asked = collections.Counter()
    grid = _diagnose._fit_grid
    fits = collections.Counter()
    fit = _diagnose._model.fit

    def counted(p, cfg, effect, values):
        asked[(effect, _diagnose._frozen(cfg))] += 1
        return grid(p, cfg, effect, values)

    def counted_fit(p, cfg, **kwargs):
        fits["n"] += 1
        return fit(p, cfg, **kwargs)

    monkeypatch.setattr(_diagnose, "_fit_grid", counted)
    monkeypatch.setattr(_diagnose._model, "fit", counted_fit)
    remembered = _diagnose.search(pair_record, candidates=CANDIDATES, solver=None, uncertainty=False)
    assert remembered["effects"], "the record's effects are not found: the test shows nothing"
    assert max(asked.values()) == 1, asked
    remembered_fits = fits["n"]

    # Without any memory: a key that matches nothing defeats the search's (its additions, its
    # pattern search's steps), and creep's lags of the input are filtered at every call.
    fits.clear()
    monkeypatch.setattr(_diagnose, "_frozen", lambda v: object())

    def filtered_every_time(q, p, v, drive, norm):
        d = p.u if q.drive == "input" else drive
        return np.asarray(_creep.lowpass(d, np.exp(-p.dt / np.asarray(q)))) - d[:, None]

    monkeypatch.setattr(EFFECT["creep"], "columns", filtered_every_time)
    recomputed = _diagnose.search(pair_record, candidates=CANDIDATES, solver=None, uncertainty=False)
    assert fits["n"] > remembered_fits, "nothing repeats on this record: the memory is not exercised"
    # The same answers to the last bit.
    assert _summary(remembered) == _summary(recomputed)
    for label in ("model_base", "model_final"):
        np.testing.assert_array_equal(remembered[label]["coef"], recomputed[label]["coef"])
        assert remembered[label]["cfg"] == recomputed[label]["cfg"]


def test_input_lags_are_filtered_once_and_equal_the_recurrence(pair_record, monkeypatch):
    p = _diagnose.prepared(pair_record, _diagnose.scaling_of(pair_record))
    q = Lags((0.05, 0.5), "input")
    filtered = []
    lowpass = _creep.lowpass

    def counted(v, lam):
        filtered.append(len(v))
        return lowpass(v, lam)

    monkeypatch.setattr(_creep, "lowpass", counted)
    first = EFFECT["creep"].columns(q, p, None, None, None)
    again = EFFECT["creep"].columns(q, p, None, None, None)
    assert len(filtered) == 1
    assert again is first and not first.flags.writeable
    # What every fit filtered before, to the last bit.
    lam = np.exp(-p.dt / np.asarray(q))
    np.testing.assert_array_equal(first, np.asarray(lowpass(p.u, lam)) - p.u[:, None])
    # The plain recurrence, sample by sample, from rest at the first input.
    state, ref = np.full(2, p.u[0]), np.empty((len(p.u), 2))
    for i, ui in enumerate(p.u):
        state = lam * state + (1 - lam) * ui
        ref[i] = state - ui
    np.testing.assert_allclose(first, ref, rtol=0, atol=1e-12)
    # Lags of the output follow the drive they are given: never kept.
    out = Lags((0.05, 0.5), "output")
    drive = np.linspace(0.0, 1.0, len(p.u))
    EFFECT["creep"].columns(out, p, drive, drive, None)
    EFFECT["creep"].columns(out, p, drive, drive, None)
    assert len(filtered) == 3
