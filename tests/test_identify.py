"""`identify`: the one call behind `piest fit`. The command's fit.json is its `to_json()`, the
validation record never changes the fit, and its option errors read as the command's."""

import json

import jax
import numpy as np
import pytest
import reference as ref

import piest_jax as pj
from piest_jax._report import json_text

R, W, OFFSET = [0.0, 0.3, 0.6], [1.0, 0.6, 0.3], 0.1


def _record(path, n, phase=0.0):
    t = np.arange(n) * 0.005
    u = np.sin(2 * np.pi * 2 * t + phase) * (1 + 0.3 * np.sin(2 * np.pi * 0.3 * t))
    y = ref.play(u, R, u[0]) @ W + OFFSET + 0.01 * np.cos(37 * t)
    np.savetxt(path, np.column_stack([t, u, y]), delimiter=",", header="t,u,y", comments="")
    return pj.load_record(path)


def _round_trip(report: dict) -> dict:
    return json.loads(json_text(report))


def test_cli_fit_json_is_identify_to_json(tmp_path, capsys):
    rec = _record(tmp_path / "d.csv", 300)
    val = _record(tmp_path / "v.csv", 200, phase=1.0)
    out = tmp_path / "out"
    argv = [
        "fit",
        rec.source,
        "--plays",
        "3",
        "--validate",
        val.source,
        "--seed",
        "3",
        "--starts",
        "2",
        "--fit-from",
        "0.1",
        "--out",
        str(out),
        "--quiet",
    ]
    assert pj.run_cli(argv) == 0
    capsys.readouterr()
    written = json.loads((out / "fit.json").read_text())
    result = pj.identify(rec, val, plays=3, key=jax.random.key(3), starts=2, fit_from=0.1)
    assert _round_trip(result.to_json()) == written
    assert written["validate"] == val.source and written["fit_from"] == 0.1
    assert written["n_fitted_samples"] == 280 == int(result.mask.sum())
    # The validation is the model run on the other record, as `compare` computes it.
    raw = pj.compare(result.fit.model().with_initial_states(val.u[0]), val, estimate_initial=False)
    assert written["validation_rmse"] == pytest.approx(float(raw.rmse), rel=1e-12)
    # The validation record never takes part: without it the fit and its report are the same.
    alone = _round_trip(pj.identify(rec, plays=3, key=jax.random.key(3), starts=2, fit_from=0.1).to_json())
    assert alone == {k: v for k, v in written.items() if not k.startswith("valid")}


def test_extrapolation_counts_the_samples_outside_the_range():
    # The range's ends count as inside; with no sample inside there is no RMSE to give.
    from piest_jax._identification.compare import extrapolation

    u, y = np.array([0.0, 0.5, 1.0, 1.5, -0.1]), np.zeros(5)
    pred = np.array([1.0, 2.0, 2.0, 9.0, 9.0])
    outside, inside = extrapolation(u, (0.0, 1.0), y, a=pred, b=2 * pred)
    assert outside == 0.4
    assert inside["a"] == pytest.approx(np.sqrt((1 + 4 + 4) / 3), rel=1e-15)
    assert inside["b"] == pytest.approx(2 * np.sqrt((1 + 4 + 4) / 3), rel=1e-15)
    assert extrapolation(u, (2.0, 3.0), y, a=pred) == (1.0, {"a": None})


@pytest.mark.parametrize("amplitude", [1.3, 0.8])
def test_validation_outside_the_identified_input_range_is_reported(tmp_path, capsys, amplitude):
    # A validation run driven further than the identification run: the share of its samples
    # outside the identified input range, and the RMSEs over the others, counted here from the
    # predictions reported; a note on stderr names it. Driven less far: nothing outside.
    rec = _record(tmp_path / "d.csv", 300)
    t = np.arange(240) * 0.005
    u = amplitude * np.sin(2 * np.pi * 2 * t)
    y = ref.play(u, R, u[0]) @ W + OFFSET
    np.savetxt(tmp_path / "v.csv", np.column_stack([t, u, y]), delimiter=",", header="t,u,y", comments="")
    val = pj.load_record(tmp_path / "v.csv")
    result = pj.identify(rec, val, model="pi", plays=3, key=jax.random.key(3), starts=2)
    report = result.to_json()
    outside = (val.u < rec.u.min()) | (val.u > rec.u.max())
    assert outside.any() == (amplitude > 1)
    assert report["validation_outside_input_range"] == pytest.approx(outside.mean(), abs=1e-15)
    inside = report["validation_inside_input_range"]
    v = result.validation
    for key, pred in (("rmse", v.raw.prediction), ("rmse_ic", v.ic.prediction)):
        assert inside[key] == pytest.approx(np.sqrt(np.mean((np.asarray(pred) - val.y)[~outside] ** 2)), rel=1e-12)
    out = tmp_path / "out"
    argv = ["fit", rec.source, "--model", "pi", "--plays", "3", "--validate", val.source, "--out", str(out), "--quiet"]
    assert pj.run_cli([*argv, "--seed", "3", "--starts", "2"]) == 0
    err = capsys.readouterr().err
    assert ("samples have inputs outside the identification record" in err) == (amplitude > 1)
    if amplitude > 1:
        assert f"{100 * outside.mean():.3g} % of {val.source}'s samples" in err
        assert f"validation_rmse_ic {inside['rmse_ic']:.4g}" in err


def test_validation_reports_the_band_coverage(tmp_path):
    # White noise on a known 3-play model: the validation record's samples fall inside the raw
    # and the IC prediction's 95 % measurement bands about 95 % of the time; the bands are those
    # of the predictions reported, and the coverage is counted from them.
    rng = np.random.default_rng(11)

    def record(path, n, phase):
        t = np.arange(n) * 0.005
        u = np.sin(2 * np.pi * 2 * t + phase) * (1 + 0.3 * np.sin(2 * np.pi * 0.3 * t))
        y = ref.play(u, R, u[0]) @ W + OFFSET + 0.01 * rng.standard_normal(n)
        np.savetxt(path, np.column_stack([t, u, y]), delimiter=",", header="t,u,y", comments="")
        return pj.load_record(path)

    rec, val = record(tmp_path / "d.csv", 400, 0.0), record(tmp_path / "v.csv", 400, 1.0)
    result = pj.identify(rec, val, model="pi", plays=3, starts=2)
    v = result.validation
    np.testing.assert_allclose(v.raw_band.prediction, v.raw.prediction, atol=1e-10)
    np.testing.assert_allclose(v.ic_band.prediction, v.ic.prediction, atol=1e-10)
    report = result.to_json()
    for key, band in (("validation_band_coverage", v.raw_band), ("validation_band_coverage_ic", v.ic_band)):
        lower, upper = (np.asarray(b) for b in band.interval(0.95))
        assert report[key] == np.mean((val.y >= lower) & (val.y <= upper))
        assert 0.9 <= report[key] <= 0.99, (key, report[key])
    fig = pj.fit_figure(val, v.raw.prediction, title="validation", band=v.raw_band.interval())
    assert any(
        f"{100 * report['validation_band_coverage']:.1f} % inside" in t.get_text()
        for t in fig.axes[1].get_legend().get_texts()
    )


def test_the_selection_is_typed_and_reported(tmp_path, capsys):
    rec = _record(tmp_path / "d.csv", 300)
    result = pj.identify(rec, model="pi", candidates=[2, 3], starts=2)
    assert isinstance(result.selection, pj.ModelSize) and result.validation is None
    assert result.fit is result.selection.fit and result.fit.n_plays == result.selection.n_plays
    rep = _round_trip(result.to_json())
    assert rep["selection"] == {
        "criterion": "holdout",
        "candidates": [2, 3],
        "scores": list(result.selection.scores),
        "rejected": [],
        "selection_samples": 300,
    }
    assert rep["n_plays"] == result.fit.n_plays and "fit_from" not in rep
    # A saved report is a model file.
    path = pj.write_json(tmp_path / "fit.json", result.to_json())
    model = pj.load_model(path)
    np.testing.assert_allclose(np.asarray(model(rec.u)), np.asarray(result.fit(rec.u)), atol=1e-12)


@pytest.mark.parametrize(
    "options, message",
    [
        (
            dict(initial_states=0.0, fit_initial_states=True),
            "give either `initial_states` or `fit_initial_states`, not both",
        ),
        (dict(plays=3, candidates=[2, 3]), "`candidates` is used only by `plays` auto; `plays` 3 fixes"),
        (dict(plays=3, criterion="bic"), "`criterion` is used only by `plays` auto"),
        (dict(model="pi", lags=[1]), r"`lags` needs `model` pi\+creep or auto"),
        (dict(lags=[1], time_constants=[0.1]), "give either `lags` or `time_constants`"),
        (dict(model="pi", time_constants=[0.1]), r"`time_constants` needs `model` pi\+creep"),
        (dict(criterion="bic"), "`criterion` bic chooses the plays only; use it with `model` pi"),
        (dict(model="creep"), "unknown `model` 'creep'"),
        (dict(plays=0), "`plays` must be a positive whole number or 'auto'"),
        (dict(candidates=[2, 2]), "`candidates` must be distinct positive whole numbers"),
        (dict(lags=0), "`lags` must be distinct positive whole numbers, got 0"),
        (dict(lags=1.5), r"`lags` must be a whole number or a list of them, got 1.5"),
        (dict(fit_from=99.0), r"d.csv: no sample at or after `fit_from` 99 \(the record ends at t = 0.195\)"),
        (dict(fit_from=float("nan")), "`fit_from` must be a finite time"),
        (dict(time_constants=[-1.0]), "`time_constants`: -1 is not positive"),
        (dict(time_constants=[1e-4]), "shorter than the sampling interval"),
        (dict(time_constants=[1e3]), "over 100 times the record's duration"),
        (dict(candidates=[30]), r"d.csv: 40 samples are too few to choose among `candidates` 30"),
    ],
)
def test_option_errors_are_raised_before_any_fit(tmp_path, monkeypatch, options, message):
    from piest_jax._identification import identify as module

    rec = _record(tmp_path / "d.csv", 40)

    def no_fit(*args, **kwargs):
        raise AssertionError("a fit started")

    for name in ("fit_pi", "select_plays", "select_model"):
        monkeypatch.setattr(module, name, no_fit)
    with pytest.raises(ValueError, match=message):
        pj.identify(rec, **options)


def test_the_command_names_its_options_in_identify_messages(tmp_path, capsys):
    rec = _record(tmp_path / "d.csv", 40)
    out = tmp_path / "o"
    assert pj.run_cli(["fit", rec.source, "--plays", "3", "--candidates", "2,3", "--out", str(out)]) == 2
    assert capsys.readouterr().err == (
        "piest fit: error: --candidates is used only by --plays auto; --plays 3 fixes the number of plays\n"
    )
    assert pj.run_cli(["fit", rec.source, "--time-constants", "1e-4", "--out", str(out)]) == 2
    assert capsys.readouterr().err.startswith("piest fit: error: --time-constants: 0.0001 is shorter")
    assert not out.exists()


def test_a_constant_input_and_other_records_are_refused(tmp_path):
    rec = _record(tmp_path / "d.csv", 40)
    flat = pj.Record.from_arrays(rec.t, np.ones(40), rec.y, source="flat")
    with pytest.raises(ValueError, match=r"flat: the input u is constant \(1\): it excites no play"):
        pj.identify(flat, plays=2)
    with pytest.raises(ValueError, match="`record` must be a Record"):
        pj.identify((rec.u, rec.y), plays=2)


def test_one_count_is_a_list_of_one(tmp_path):
    from piest_jax._identification.identify import plan

    rec = _record(tmp_path / "d.csv", 400)
    one = plan(rec, model="pi+creep", plays=2, lags=1)
    assert one.lags == plan(rec, model="pi+creep", plays=2, lags=[1]).lags == (1,)
    assert plan(rec, candidates=np.int64(3)).plays == plan(rec, candidates=[3]).plays == (3,)
