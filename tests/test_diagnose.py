"""The diagnosis workflow: noise floor, input checks, locating, naming (a confusion matrix over
generated records with hidden effects), and the `piest diagnose` command."""

import dataclasses
import json

import jax
import numpy as np
import pytest

import piest_jax as pj
from piest_jax._cli import main
from piest_jax._data.record import DataError, Record, load_record
from piest_jax._diagnosis import diagnose as _diagnose
from piest_jax._diagnosis import hidden as _hidden
from piest_jax._diagnosis import locate as _locate
from piest_jax._diagnosis.effects import EFFECTS
from piest_jax._parameter_table import rounded
from piest_jax._report import json_text

pytestmark = pytest.mark.long

N_SAMPLES = 500


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
        (lambda r: Record(r.t, -np.abs(r.t - r.t[len(r.t) // 2]), r.y), "reverses direction only once"),
        (lambda r: Record(r.t, r.u, np.full(len(r.t), 3.0)), "constant output"),
    ],
)
def test_bad_records_are_refused(change, match):
    with pytest.raises(DataError, match=match):
        _diagnose.search(change(_sine_record()))


def test_a_validation_record_is_only_predicted():
    # A short record or one loop (down, then up) is a fair target for a prediction, though no
    # record to identify on; what no prediction can use (a constant output, whose fit
    # percentage would divide by zero) is still refused.
    rec = _sine_record()
    one_loop = Record(rec.t[:300], np.cos(np.pi * rec.t[:300] / 1.5), rec.y[:300])
    with pytest.raises(DataError, match="reverses direction only once"):
        _diagnose.check_record(one_loop)
    _diagnose.check_record(one_loop, validation=True)
    _diagnose.check_record(rec.slice(0, 50), validation=True)
    with pytest.raises(DataError, match="constant output"):
        _diagnose.check_record(Record(rec.t, rec.u, np.full(len(rec.t), 3.0)), validation=True)
    with pytest.raises(DataError, match="`y` has 1 NaN"):
        _diagnose.check_record(Record(rec.t, rec.u, np.where(rec.t == rec.t[4], np.nan, rec.y)), validation=True)


def test_regimes_and_locate_find_a_structured_window():
    rec = _sine_record(n=1000, noise=0.0)
    reg = _locate.regimes(rec.t, rec.u)
    un = (rec.u - rec.u.min()) / np.ptp(rec.u)
    ext = un[reg["extremes"]]
    assert np.all(ext > 0.9 - 1e-12) or np.all((ext > 0.9) | (ext < 0.1))
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


def test_generated_delay_is_a_fraction_of_the_record():
    # A delay drawn in samples would shrink against the input's cycle as records grow, until no
    # length's naming bar could see it; drawn as a fraction of the record, it is the same phase lag
    # at every length (the draws are the same: the effect's seed does not depend on the length).
    key = jax.random.PRNGKey(11)

    def delay_samples(n):
        form = _hidden.generate(("delay",), key=key, n_samples=n)[1]["forms"]["delay"]
        return float(form.split("by ")[1].split()[0])

    short = delay_samples(500)
    assert 1.5 <= short <= 8.0
    for n in (200, 5000):  # the forms print two decimals: each side is off by up to 0.005
        assert delay_samples(n) == pytest.approx(n / 500 * short, abs=0.005 * (1 + n / 500))


def test_generator_coloured_noise():
    from scipy.signal import lfilter

    key = jax.random.PRNGKey(3)
    white, tw = _hidden.generate(("creep",), key=key, n_samples=400)
    same, ts = _hidden.generate(("creep",), key=key, n_samples=400, noise_ar=0.0)
    np.testing.assert_array_equal(white.y, same.y)
    coloured, tc = _hidden.generate(("creep",), key=key, n_samples=400, noise_ar=0.9)
    assert tc["noise_ar"] == 0.9 and tw["noise_ar"] == 0.0 and not np.array_equal(white.y, coloured.y)
    # The AR(1) filter against scipy's: e_0 = w_0, e_t = φ e_{t-1} + √(1 - φ²) w_t.
    w = np.random.default_rng(0).normal(0, 2.0, 200_000)
    phi = 0.8
    b = np.sqrt(1 - phi**2)
    ref = lfilter([b], [1.0, -phi], w, zi=[(1 - b) * w[0]])[0]
    e = _hidden._ar1(w.copy(), phi)
    np.testing.assert_allclose(e, ref, rtol=1e-12, atol=1e-12)
    # Stationary: the std stays σ, the lag-one autocorrelation is φ (sampling error ~ 1/√N).
    assert abs(np.std(e) / 2.0 - 1) < 0.02
    assert abs(np.corrcoef(e[:-1], e[1:])[0, 1] - phi) < 0.01
    for bad in (-0.1, 1.0, float("nan"), "0.5"):
        with pytest.raises(ValueError, match="`noise_ar` must be a number in \\[0, 1\\)"):
            _hidden.generate((), key=key, noise_ar=bad)


# The confusion matrix over generated records: every record is searched with every registered effect.
# The bars: the right effect named in >= 90 % of single-effect records, no effect in >= 90 %
# of effect-free ones, the final RMSE within 1.5x the noise when the right effect is named, and
# both names for two-effect records. experiments/diagnose_confusion.py runs many more records.
PER_EFFECT = 4
N_FREE = 8
PAIRS = [
    ("delay", "asymmetry"),
    ("linear_dynamics", "offset_drift"),
    ("creep", "asymmetry"),
    ("initial_state", "rate_dependence"),
    ("rate_dependence", "offset_drift"),
    ("linear_dynamics", "minor_loop_noncongruence"),
    ("saturation", "creep"),
]
# asymmetry + saturation is measured by the experiment only: both bend the loop's ends, and the
# one named first leaves less of the other than the naming rule asks (docs/diagnosis.md).
PER_PAIR = 2


@pytest.fixture(scope="module")
def confusion():
    key = jax.random.PRNGKey(7)
    classes = [((), N_FREE)] + [((e,), PER_EFFECT) for e in EFFECTS] + [(p, PER_PAIR) for p in PAIRS]
    rows = []
    for cls, n in classes:
        for i in range(n):
            rec, truth = _hidden.generate(cls, key=pj.hidden_effect_key(key, cls, i), n_samples=N_SAMPLES)
            # Naming does not depend on the final joint refinement (tests/test_refine.py), and
            # the refinement is only kept when it lowers the error: the grid fit is the bound.
            s = _diagnose.search(rec, solver=None, uncertainty=False)
            _, rmse = _diagnose.evaluate(rec, s["scaling"], s["model_final"])
            rows.append((cls, s["effects"], rmse / truth["noise_std"], truth["forms"]))
    return rows


def test_confusion_no_effect(confusion):
    free = [(named, ratio) for cls, named, ratio, _ in confusion if cls == ()]
    assert sum(named == [] for named, _ in free) >= 0.9 * len(free), free
    # With nothing to add, the plain PI model is already at the noise floor.
    assert all(ratio <= 1.5 for named, ratio in free if named == []), free


def test_confusion_single_effects(confusion):
    single = [(cls[0], named, ratio, forms) for cls, named, ratio, forms in confusion if len(cls) == 1]
    right = [(e, ratio) for e, named, ratio, _ in single if named == [e]]
    assert len(right) >= 0.9 * len(single), [(e, n, f) for e, n, _, f in single if n != [e]]
    assert all(ratio <= 1.5 for _, ratio in right), [(e, r) for e, r in right if r > 1.5]
    for e in EFFECTS:  # no effect is missed wholesale
        assert sum(x == e for x, _ in right) >= PER_EFFECT - 1, (e, single)


def test_confusion_two_effects(confusion):
    pairs = [(set(cls), set(named), ratio) for cls, named, ratio, _ in confusion if len(cls) == 2]
    right = [ratio for c, n, ratio in pairs if c == n]
    assert len(right) >= 0.9 * len(pairs), pairs
    assert all(ratio <= 1.5 for ratio in right), pairs


def test_effects_are_named_in_order():
    # The order is that of the rounds: each name was the best-scoring candidate of its round.
    rec, _ = _hidden.generate(("delay", "asymmetry"), key=jax.random.PRNGKey(200), n_samples=N_SAMPLES)
    s = _diagnose.search(rec)
    assert sorted(s["effects"]) == ["asymmetry", "delay"], s["rounds"]
    bests = [r["best"] for r in s["rounds"] if r["named"]]
    assert [b for b in bests if b in s["effects"]] == s["effects"]
    for r in s["rounds"]:
        c = r["candidates"]
        assert r["best"] == max(c, key=lambda k: c[k]["score"])
        assert r["named"] == c[r["best"]]["significant"]


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
    argv = [
        "diagnose",
        str(csv_files[0]),
        "--validate",
        str(csv_files[1]),
        "--out",
        str(out),
        "--json",
        "--candidates",
        "delay",
        "--max-effects",
        "1",
    ]
    assert main(argv) == 0
    captured = capsys.readouterr()
    printed = captured.out
    rep = json.loads((out / "report.json").read_text())
    # A validation input outside the identified range is noted, with the RMSEs inside it.
    # (This pair's validation record is driven further than the identification record.)
    share = rep["validation"]["outside_input_range"]
    assert 0 < share < 1 and "samples have inputs outside the identification record's input range" in captured.err
    assert "| RMSE, validation record, inputs inside the identified range" in (out / "report.md").read_text()
    # --json prints the report itself, the same text as the file.
    assert printed == (out / "report.json").read_text()
    for k in ("effects", "baseline_rmse", "final_rmse", "noise_std_estimate", "candidates", "where", "validation"):
        assert k in rep
    assert rep["effects"][0] == "delay"
    assert rep["final_rmse"] < rep["baseline_rmse"]
    assert set(rep["candidates"]) == {"delay"}
    for model in ("model_base", "model_final"):
        ref = rep["refinement"][model]
        assert ref["result"] in ("successful", "nonlinear_max_steps_reached"), ref
        # The grid fit is kept unless the refinement beats it at the full rate.
        assert ref["rmse"] <= ref["rmse_start"] and (ref["kept"] == "grid") == (ref["rmse"] == ref["rmse_start"]), ref
    # The reported model is the one the refinement kept.
    assert rep["refinement"]["model_final"]["rmse"] == pytest.approx(rep["final_rmse"], rel=1e-9)
    assert {"baseline_rmse", "final_rmse"} <= set(rep["validation"])
    v = rep["validation"]
    # Estimating the offset and initial states can only bring the model closer to the record.
    assert v["baseline_rmse_ic"] <= v["baseline_rmse"] and v["final_rmse_ic"] <= v["final_rmse"]
    assert v["final_fit_percent_ic"] >= v["final_fit_percent"]
    assert rep["transferable_effects"] == ["delay"] and rep["record_specific_effects"] == []
    assert v["effects_used"] == ["delay"]
    assert (out / "report.png").stat().st_size > 0 and "# Diagnosis" in (out / "report.md").read_text()
    # The named delay's value and standard error, in report.json and as a table in report.md.
    u = rep["uncertainty"]
    assert u["values"]["delay.delay_s"] == rep["parameters"]["delay"]["delay_s"]
    assert u["std_errors"]["delay.delay_s"] > 0
    value, se = rounded(u["values"]["delay.delay_s"], u["std_errors"]["delay.delay_s"])
    assert f"| delay.delay_s | {value} | {se} |" in (out / "report.md").read_text()


@pytest.mark.parametrize(
    "extra, match",
    [
        (["--candidates", "delay,hysteresis"], "unknown effect 'hysteresis'"),
        (["--max-effects", "0"], "--max-effects must be at least 1"),
    ],
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


def test_cli_report_is_the_diagnosis_json(csv_files, tmp_path):
    out = tmp_path / "diag"
    options = ["--candidates", "delay", "--max-effects", "1"]
    assert main(["diagnose", str(csv_files[0]), "--validate", str(csv_files[1]), "--out", str(out), *options]) == 0
    rep = json.loads((out / "report.json").read_text())
    rec, val = load_record(csv_files[0]), load_record(csv_files[1])
    d = pj.diagnose(rec, val, max_effects=1, candidates=["delay"])
    # report.json is the diagnosis's report plus where its records came from, in the same order.
    expected = d.to_json()
    expected["data"] = str(csv_files[0])
    expected["validation"]["data"] = str(csv_files[1])
    assert list(rep) == list(expected) and list(rep["validation"]) == list(expected["validation"])
    # The order report.json has always had, which `Diagnosis.to_json` documents.
    assert list(rep) == [
        "effects",
        "transferable_effects",
        "record_specific_effects",
        "baseline_rmse",
        "final_rmse",
        "noise_std_estimate",
        "candidates",
        "parameters",
        "uncertainty",
        "refinement",
        "rounds",
        "pruned",
        "heldout",
        "n_samples",
        "search_step",
        "where",
        "loop",
        "validation",
        "data",
    ]
    assert list(rep["validation"]) == [
        "baseline_rmse",
        "final_rmse",
        "baseline_rmse_ic",
        "final_rmse_ic",
        "baseline_fit_percent",
        "final_fit_percent",
        "baseline_fit_percent_ic",
        "final_fit_percent_ic",
        "initial_conditions",
        "noise_std_estimate",
        "baseline_rmse_offset_removed",
        "final_rmse_offset_removed",
        "effects_used",
        "outside_input_range",
        "inside_input_range",
        "data",
    ]
    assert rep == json.loads(json_text(expected))
    assert "_arrays" not in rep and "data" not in d
    # The typed fields are the ones the report and the figure show.
    assert isinstance(d.validation, pj.DiagnosisValidation) and d.record is rec and d.validation.record is val
    assert d.effects == ["delay"] == d.transferable_effects and d.record_specific_effects == []
    for y, pred, rmse in (
        (rec.y, d.final_prediction, d.final_rmse),
        (rec.y, d.baseline_prediction, d.baseline_rmse),
        (val.y, d.validation.final_prediction, d.validation.final_rmse),
    ):
        assert pred.shape == y.shape and np.sqrt(np.mean((pred - y) ** 2)) == pytest.approx(rmse, rel=1e-12)
    assert np.std(val.y - d.validation.baseline_prediction) == pytest.approx(
        d.validation.baseline_rmse_offset_removed, rel=1e-12
    )
    # Where the validation input leaves the identification record's range, counted here.
    outside = (val.u < rec.u.min()) | (val.u > rec.u.max())
    assert d.validation.outside_input_range == pytest.approx(outside.mean(), abs=1e-15)
    for name, pred in (
        ("final_rmse", d.validation.final_prediction),
        ("baseline_rmse", d.validation.baseline_prediction),
    ):
        inside = np.sqrt(np.mean((pred - val.y)[~outside] ** 2))
        assert d.validation.inside_input_range[name] == pytest.approx(inside, rel=1e-12)


def test_diagnosis_reads_as_its_report():
    rec, _ = _hidden.generate(("delay",), key=jax.random.PRNGKey(100), n_samples=300)
    d = pj.diagnose(rec, max_effects=1, candidates=["delay", "creep"], solver=None)
    report = d.to_json()
    assert list(d) == list(report) and len(d) == len(report) and dict(d) == report and d == report
    assert d == dataclasses.replace(d, final_prediction=2 * d.final_prediction)  # equal reports
    assert d != dataclasses.replace(d, final_rmse=2 * d.final_rmse)
    assert d["effects"] == d.effects and d["heldout"] == {
        "baseline_rmse": d.heldout_baseline_rmse,
        "final_rmse": d.heldout_final_rmse,
    }
    assert d["candidates"] == d.rounds[0]["candidates"] and set(d.candidates) == {"delay", "creep"}
    assert d["n_samples"] == rec.n_samples == d.n_samples
    assert "validation" not in d and d.get("validation") is None and d.validation is None
    with pytest.raises(KeyError):
        d["_arrays"]
    # Each report is a new object: changing one leaves the diagnosis as it was.
    report["rounds"][0]["best"] = "changed"
    report["effects"].append("changed")
    assert d.to_json()["rounds"][0]["best"] != "changed" and d.effects == d["effects"] != report["effects"]
    with pytest.raises(TypeError):
        d["effects"] = []
    assert len(d.figure().axes) == 4
