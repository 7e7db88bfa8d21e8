"""The diagnosis workflow: noise floor, input checks, locating, naming (a confusion matrix over
generated records with hidden effects), and the `piest diagnose` command."""

import json

import jax
import numpy as np
import pytest

from piest_jax import _diagnose, _effects, _hidden, _locate
from piest_jax._cli import main
from piest_jax._data import DataError, Record

N_SAMPLES = 500  # pads to the 512-sample length the model tests compile for


def _sine_record(n=600, noise=0.01, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.01
    u = np.sin(2 * np.pi * 1.0 * t)
    return Record(t, u, 2 * u + 0.2 * np.sign(np.cos(2 * np.pi * t)) + noise * rng.normal(size=n))


def test_noise_floor_estimate():
    rng = np.random.default_rng(0)
    t = np.linspace(0, 10, 5000)
    y = np.sin(2 * np.pi * 0.7 * t) + np.abs(np.sin(2 * np.pi * 0.3 * t)) + 0.05 * rng.normal(size=5000)
    assert _diagnose.noise_std(y) == pytest.approx(0.05, rel=0.08)


@pytest.mark.parametrize(
    "change, match",
    [
        (lambda r: r.slice(0, 50), "too short: 50 samples"),
        (lambda r: Record(r.t, np.where(np.arange(len(r.t)) == 7, np.nan, r.u), r.y), "`u` has 1 NaN/inf values"),
        (lambda r: Record(r.t, r.u, np.where(np.arange(len(r.t)) == 9, np.inf, r.y)), "`y` has 1 NaN"),
        (lambda r: Record(r.t, np.full(len(r.t), 2.0), r.y), "no excitation: the input u is constant"),
        (lambda r: Record(r.t, r.t.copy(), r.y), "never reverses direction"),
        (lambda r: Record(r.t, r.u, np.full(len(r.t), 3.0)), "constant output"),
    ],
)
def test_bad_records_are_refused(change, match):
    with pytest.raises(DataError, match=match):
        _diagnose.search(change(_sine_record()))


def test_regimes_and_locate_find_a_structured_window():
    rec = _sine_record(n=1000, noise=0.0)
    reg = _locate.regimes(rec.t, rec.u)
    un = (rec.u - rec.u.min()) / np.ptp(rec.u)
    assert np.all(un[reg["extremes"]] > 0.9 - 1e-12) or np.all((un[reg["extremes"]] > 0.9) | (un[reg["extremes"]] < 0.1))
    assert reg["start-up"][0] and not reg["start-up"][-1]
    rng = np.random.default_rng(1)
    pred = rec.y + 0.01 * rng.normal(size=1000)
    pred[300:400] += 0.2  # a disagreement confined to the fourth window
    where = _locate.locate(rec.t, rec.u, rec.y, pred, 0.01)
    flagged = [w for w in where if w["structured"] and w["kind"] == "window"]
    assert [w["name"] for w in flagged] == ["t = 3..3.99"]
    assert where[0] is flagged[0]  # structured places come first
    noise_only = _locate.locate(rec.t, rec.u, rec.y, rec.y + 0.01 * rng.normal(size=1000), 0.01)
    assert not any(w["structured"] for w in noise_only if w["kind"] != "correlation")


def test_generator_is_reproducible_and_checks_names():
    key = jax.random.PRNGKey(3)
    a, ta = _hidden.generate(("creep",), key=key, n_samples=400)
    b, tb = _hidden.generate(("creep",), key=key, n_samples=400)
    np.testing.assert_array_equal(a.y, b.y)
    assert ta == tb and ta["effects"] == ["creep"]
    assert np.all(a.u[:10] == a.u[0])  # starts at rest
    with pytest.raises(ValueError, match="unknown effect 'magic'"):
        _hidden.generate(("magic",), key=key)


# Hidden-effect records, one per effect. Each search tries the hidden effect only (the choice
# among all seven, over many records, is the confusion matrix of experiments/diagnose_confusion.py),
# except where the choice between two close explanations is the point: a delay against a lag.
RIVAL = {"delay": "linear_dynamics"}


def _hidden_record(effects, i):
    return _hidden.generate(effects, key=jax.random.fold_in(jax.random.PRNGKey(7), i), n_samples=N_SAMPLES)


@pytest.mark.parametrize("i, effect", list(enumerate(_effects.EFFECTS)))
def test_hidden_effect_is_named(i, effect):
    rec, truth = _hidden_record((effect,), i)
    cands = (effect, RIVAL[effect]) if effect in RIVAL else (effect,)
    s = _diagnose.search(rec, candidates=cands, max_effects=1, refit=False)
    assert s["effects"] == [effect], (truth["forms"], s["rounds"])
    _, rmse = _diagnose.evaluate(rec, s["scaling"], s["theta_final"], s["effects"])
    _, rmse_base = _diagnose.evaluate(rec, s["scaling"], s["theta_base"], [])
    assert rmse <= 1.5 * truth["noise_std"] < rmse_base, (rmse, rmse_base, truth["noise_std"])


def test_no_effect_gives_no_effect():
    rec, truth = _hidden_record((), 100)
    s = _diagnose.search(rec, candidates=("creep", "offset_drift"), max_effects=1, refit=False)
    assert s["effects"] == [], s["rounds"]
    assert s["rounds"][0]["named"] is False
    _, rmse = _diagnose.evaluate(rec, s["scaling"], s["theta_base"], [])
    assert rmse <= 1.5 * truth["noise_std"]


def test_two_hidden_effects_are_both_named():
    rec, truth = _hidden_record(("delay", "asymmetry"), 200)
    s = _diagnose.search(rec, candidates=("delay", "asymmetry"), max_effects=2, refit=False)
    assert sorted(s["effects"]) == ["asymmetry", "delay"], (truth["forms"], s["rounds"], s["pruned"])
    # In order: the first named is the one that removed more held-out error in the first round.
    first = s["rounds"][0]["candidates"]
    assert s["effects"][0] == max(first, key=lambda k: first[k]["score"])


def test_unknown_candidate_is_refused():
    with pytest.raises(ValueError, match="unknown effect 'drift'"):
        _diagnose.search(_sine_record(), candidates=("drift",))


@pytest.fixture(scope="module")
def csv_files(tmp_path_factory):
    d = tmp_path_factory.mktemp("diag")
    paths = []
    for i, eff in enumerate([("delay",), ()]):
        rec, _ = _hidden.generate(eff, key=jax.random.PRNGKey(100 + i), n_samples=N_SAMPLES)
        p = d / f"rec{i}.csv"
        p.write_text("t,u,y\n" + "\n".join(f"{a},{b},{c}" for a, b, c in zip(rec.t, rec.u, rec.y)))
        paths.append(p)
    return paths


def test_cli_writes_the_report(csv_files, tmp_path, capsys):
    out = tmp_path / "diag"
    argv = ["diagnose", str(csv_files[0]), "--validate", str(csv_files[1]), "--out", str(out), "--json",
            "--candidates", "delay", "--max-effects", "1"]
    assert main(argv) == 0
    printed = capsys.readouterr().out.split()
    assert printed == [str(out / "report.json")]
    rep = json.loads((out / "report.json").read_text())
    for k in ("effects", "baseline_rmse", "final_rmse", "noise_std_estimate", "candidates", "where", "validation"):
        assert k in rep
    assert rep["effects"][0] == "delay"
    assert rep["final_rmse"] < rep["baseline_rmse"]
    assert set(rep["candidates"]) == {"delay"}
    assert {"baseline_rmse", "final_rmse"} <= set(rep["validation"])
    assert (out / "report.png").stat().st_size > 0 and "# Diagnosis" in (out / "report.md").read_text()


@pytest.mark.parametrize(
    "extra, match",
    [(["--candidates", "delay,hysteresis"], "unknown effect 'hysteresis'"),
     (["--max-effects", "0"], "--max-effects must be at least 1")],
)
def test_cli_bad_options_are_one_line(csv_files, tmp_path, capsys, extra, match):
    assert main(["diagnose", str(csv_files[0]), "--out", str(tmp_path / "o"), *extra]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and match in err


def test_cli_missing_file_is_one_line(tmp_path, capsys):
    assert main(["diagnose", str(tmp_path / "nope.csv"), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "nope.csv" in err


def test_cli_bad_input_is_one_line(tmp_path, capsys):
    p = tmp_path / "flat.csv"
    t = np.arange(300) * 0.01
    p.write_text("t,u,y\n" + "\n".join(f"{a},{np.sin(a * 6)},1.0" for a in t))
    assert main(["diagnose", str(p), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "constant output" in err
