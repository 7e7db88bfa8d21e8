"""`piest fit --model gpi|preisach` and `piest compensate` on their fit.json files."""

import json

import numpy as np
import pytest

import piest_jax as pj
from piest_jax._cli import main

R, W = np.array([0.0, 0.3, 0.8]), np.array([0.9, 0.5, 0.3])
A, C, S, OFFSET = [1.2, 0.4], [0.1, 0.9], [1.0, 2.0], 0.3


def plant(u):
    return np.asarray(pj.GeneralizedPI(pj.PIOperator(R, W, u[0]), A, C, S, OFFSET)(u))


def signal(T=300, grow=0.7, freq=4):
    t = np.linspace(0.0, 1.0, T)
    return 2.0 * np.sin(2 * np.pi * freq * t) * (1 - grow + grow * t)


def write(path, u, y):
    t = np.arange(len(u)) * 0.01
    np.savetxt(path, np.column_stack([t, u, y]), delimiter=",", header="t,u,y", comments="")
    return path


def desired(path, yd):
    t = np.arange(len(yd)) * 0.01
    np.savetxt(path, np.column_stack([t, yd]), delimiter=",", header="t,desired", comments="")
    return path


def rmse(a, b):
    return float(np.sqrt(np.mean((np.asarray(a) - np.asarray(b)) ** 2)))


def test_cli_fit_and_compensate_gpi(tmp_path, capsys):
    u, uv = signal(), signal(200, 0.3, 3)
    noise = 1e-3 * np.random.default_rng(0).standard_normal(u.size)
    write(tmp_path / "d.csv", u, plant(u) + noise)
    write(tmp_path / "v.csv", uv, plant(uv))
    out = tmp_path / "out"
    assert (
        main(
            [
                "fit",
                str(tmp_path / "d.csv"),
                "--model",
                "gpi",
                "--plays",
                "3",
                "--validate",
                str(tmp_path / "v.csv"),
                "--out",
                str(out),
                "--quiet",
            ]
        )
        == 0
    )
    capsys.readouterr()
    rep = json.loads((out / "fit.json").read_text())
    assert rep["structure"] == "gpi"
    assert rep["model"] == {"structure": "gpi", "n_plays": 3, "n_terms": 2}
    g = rep["output_function"]
    assert g["form"] == "tanh" and len(g["amplitudes"]) == len(g["centres"]) == len(g["scales"]) == 2
    for key in ("thresholds", "weights", "offset", "initial_states", "rmse", "solver", "input_range"):
        assert key in rep
    assert rep["solver"]["result"] == "successful"
    assert {p.name for p in out.iterdir()} == {"fit.json", "fit.md", "fit.png", "validation.png"}
    # fit.json is a model file reproducing its rmse; the validation record is predicted.
    model = pj.load_model(out / "fit.json")
    assert isinstance(model, pj.GeneralizedPI)
    assert rmse(model(u), plant(u) + noise) == pytest.approx(rep["rmse"], rel=1e-9)
    assert rep["rmse"] < 2e-3
    assert rep["validation_rmse"] < 0.01 * np.ptp(plant(uv))
    # piest compensate inverts it: the model driven by u follows the desired output.
    yd = OFFSET + 1.0 * np.sin(np.linspace(0, 4 * np.pi, 150))
    desired(tmp_path / "yd.csv", yd)
    assert (
        main(["compensate", str(out / "fit.json"), str(tmp_path / "yd.csv"), "--out", str(tmp_path / "ff"), "--quiet"])
        == 0
    )
    cols = np.loadtxt(tmp_path / "ff" / "compensate.csv", delimiter=",", skiprows=1)
    np.testing.assert_allclose(cols[:, 3], yd, atol=1e-9)
    np.testing.assert_allclose(np.asarray(model(cols[:, 2])), yd, atol=1e-9)
    np.testing.assert_allclose(cols[:, 2], np.asarray(pj.feedforward(model, yd)), atol=1e-12)
    summary = json.loads((tmp_path / "ff" / "compensate.json").read_text())
    assert summary["structure"] == "gpi" and summary["max_model_error"] < 1e-9


def test_cli_fit_and_compensate_preisach(tmp_path, capsys):
    u = signal(400)
    write(tmp_path / "d.csv", u, plant(u))
    out = tmp_path / "out"
    assert (
        main(["fit", str(tmp_path / "d.csv"), "--model", "preisach", "--grid", "6,8", "--out", str(out), "--quiet"])
        == 0
    )
    capsys.readouterr()
    rep = json.loads((out / "fit.json").read_text())
    assert rep["structure"] == "preisach"
    assert rep["model"] == {"structure": "preisach", "grid": [6, 8], "monotone": True}
    assert np.asarray(rep["density"]).shape == (6, 8) and np.min(rep["density"]) >= 0
    assert len(rep["half_widths"]) == 6 and len(rep["centres"]) == len(rep["blur"]) == 8
    assert rep["smoothness"] in rep["smoothness_candidates"]
    assert len(rep["held_out_rmse"]) == len(rep["smoothness_candidates"])
    assert rep["starts_at_rest"] is True
    model = pj.load_model(out / "fit.json")
    assert isinstance(model, pj.Preisach)
    assert rmse(model(u), plant(u)) == pytest.approx(rep["rmse"], rel=1e-7)
    yd = plant(u)[:150] * 0.8
    desired(tmp_path / "yd.csv", yd)
    assert (
        main(["compensate", str(out / "fit.json"), str(tmp_path / "yd.csv"), "--out", str(tmp_path / "ff"), "--quiet"])
        == 0
    )
    cols = np.loadtxt(tmp_path / "ff" / "compensate.csv", delimiter=",", skiprows=1)
    np.testing.assert_allclose(np.asarray(model(cols[:, 2])), yd, atol=1e-9)
    np.testing.assert_allclose(cols[:, 3], yd, atol=1e-9)


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--model", "gpi"], "--model gpi needs --plays N"),
        (["--model", "gpi", "--plays", "2", "--lags", "1"], "--lags does not apply to --model gpi"),
        (["--model", "gpi", "--plays", "2", "--signed-weights"], "--signed-weights does not apply to --model gpi"),
        (["--model", "gpi", "--plays", "2", "--grid", "4,4"], "--grid does not apply to --model gpi"),
        (["--model", "preisach", "--plays", "3"], "--plays does not apply to --model preisach"),
        (["--model", "preisach", "--solver", "gn"], "--solver does not apply to --model preisach"),
        (["--model", "preisach", "--terms", "1"], "--terms does not apply to --model preisach"),
        (["--model", "preisach", "--smoothness", "-1"], "--smoothness must be finite and >= 0"),
        (["--model", "preisach", "--grid", "40,40"], "coefficients (its triangle and the offset)"),
        (["--model", "pi", "--smoothness", "0.1"], "--smoothness is used only by --model preisach"),
        (["--terms", "2"], "--terms is used only by --model gpi, not --model auto"),
    ],
)
def test_cli_fit_refuses_what_a_model_ignores(tmp_path, capsys, extra, message):
    u = signal(120)
    write(tmp_path / "d.csv", u, plant(u))
    out = tmp_path / "out"
    assert main(["fit", str(tmp_path / "d.csv"), *extra, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_cli_compensate_refuses_unreachable_and_non_invertible(tmp_path, capsys):
    g = pj.GeneralizedPI(pj.PIOperator(R, W), A, C, S, OFFSET)
    pj.save_model(tmp_path / "g.json", g)
    desired(tmp_path / "yd.csv", np.array([0.0, 1.0, 2.0]))  # the range is (-1.3, 1.9)
    assert main(["compensate", str(tmp_path / "g.json"), str(tmp_path / "yd.csv"), "--out", str(tmp_path / "a")]) == 2
    err = capsys.readouterr().err
    assert "outside the range the model saturates at" in err and len(err.strip().splitlines()) == 1
    p = pj.Preisach([0.0, 0.5], [-0.5, 0.5], [[1.0, -0.2], [0.3, 0.1]])
    pj.save_model(tmp_path / "p.json", p)
    assert main(["compensate", str(tmp_path / "p.json"), str(tmp_path / "yd.csv"), "--out", str(tmp_path / "b")]) == 2
    err = capsys.readouterr().err
    assert "cannot be inverted" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


def test_feedforward_uses_the_models_own_inverse():
    g = pj.GeneralizedPI(pj.PIOperator(R, W, 0.2), A, C, S, OFFSET)
    yd = OFFSET + np.sin(np.linspace(0, 6, 120))
    u = pj.feedforward(g, yd)
    np.testing.assert_allclose(np.asarray(g(u)), yd, atol=1e-10)
    # Given states are made admissible and used for the start.
    u2 = pj.feedforward(g, yd, initial_states=[0.0, 0.5, 0.1])
    start = g.with_initial_states(pj.admissible_states(R, [0.0, 0.5, 0.1]))
    np.testing.assert_allclose(np.asarray(start(u2)), yd, atol=1e-10)
    with pytest.raises(ValueError, match="no separate offset or creep"):
        pj.feedforward(g, yd, offset=0.1)


def test_identify_fits_them_as_the_command_does(tmp_path, capsys):
    # `piest fit --model gpi|preisach` is `identify`: the same fit, its to_json the fit.json.
    import jax

    u, uv = signal(), signal(200, 0.3, 3)
    rec = pj.load_record(write(tmp_path / "d.csv", u, plant(u)))
    val = pj.load_record(write(tmp_path / "v.csv", uv, plant(uv)))
    for model, extra, options in (
        ("gpi", ["--plays", "3", "--starts", "2"], dict(plays=3, starts=2)),
        ("preisach", ["--grid", "6,6"], dict(grid=(6, 6))),
    ):
        out = tmp_path / model
        assert (
            main(["fit", rec.source, "--model", model, *extra, "--validate", val.source, "--out", str(out), "--quiet"])
            == 0
        )
        capsys.readouterr()
        got = pj.identify(rec, val, model=model, key=jax.random.key(0), **options)
        assert isinstance(got.fit, pj.GPIFit if model == "gpi" else pj.PreisachFit)
        assert got.validation.ic is None
        np.testing.assert_allclose(got.validation.raw.rmse, rmse(got.validation.raw.prediction, val.y))
        want = json.loads((out / "fit.json").read_text())
        assert json.loads(pj.write_json(tmp_path / f"{model}.json", got.to_json()).read_text()) == want
        assert want["validation_rmse"] == pytest.approx(float(got.validation.raw.rmse))
        # validation_fit_percent and _ic are the PI models' prediction with estimated initial
        # conditions; these models have none, so the keys are absent rather than meaning another thing.
        assert not {"validation_fit_percent", "validation_rmse_ic"} & set(want)


def test_defaults_given_explicitly_are_not_refused():
    from piest_jax._identification.identify import check_options

    check_options(model="gpi", plays=np.int64(2), positive_weights=np.True_, solver="lm")
    check_options(model="preisach", starts=np.int64(4), max_steps=100.0, fit_initial_states=np.False_)


@pytest.mark.parametrize(
    "options, message",
    [
        (dict(model="gpi"), "`model` gpi needs `plays` N"),
        (dict(model="gpi", plays=2, lags=[1]), "`lags` does not apply to `model` gpi"),
        (
            dict(model="gpi", plays=2, positive_weights=False),
            r"signed weights \(`positive_weights` False\) does not apply to `model` gpi",
        ),
        (dict(model="gpi", plays=2, terms=0), "`terms` must be a positive whole number, got 0"),
        (dict(model="preisach", starts=2), "`starts` does not apply to `model` preisach"),
        (dict(model="preisach", plays=3), "`plays` does not apply to `model` preisach"),
        (dict(model="preisach", grid=(4,)), r"`grid` must be two positive whole numbers"),
        (dict(model="preisach", smoothness=-1.0), "`smoothness` must be finite and >= 0, got -1"),
        (dict(model="pi", terms=2), "`terms` is used only by `model` gpi, not `model` pi"),
        (dict(grid=(4, 4)), "`grid` is used only by `model` preisach, not `model` auto"),
    ],
)
def test_identify_refuses_what_a_model_ignores(tmp_path, options, message):
    u = signal()
    rec = pj.load_record(write(tmp_path / "d.csv", u, plant(u)))
    with pytest.raises(ValueError, match=message):
        pj.identify(rec, **options)
