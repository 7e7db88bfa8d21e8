"""Model files: `save_model`/`load_model` round trips, `piest fit`'s fit.json read back, and every
rejection with its message."""

import json

import numpy as np
import pytest

import piest_jax as pj
from piest_jax._identification.model_file import SCHEMA, model_keys

R, W, C, X0 = [0.0, 0.4, 1.1], [1.0, 0.6, 0.3], 0.25, [0.1, -0.2, 0.0]


def pi_model(x0=X0, offset=C):
    return pj.HysteresisModel(pj.PIOperator(R, W, x0), None, offset)


def _record(tmp_path, n=600, noise=0.0):
    t = np.arange(n) * 0.005
    u = 2.0 * np.sin(2 * np.pi * 0.7 * t) * (1 + 0.4 * np.sin(2 * np.pi * 0.13 * t))
    y = np.asarray(pi_model(0.0)(u))
    y = y + noise * np.random.default_rng(0).standard_normal(n)
    path = tmp_path / "rec.csv"
    np.savetxt(path, np.column_stack([t, u, y]), delimiter=",", header="t,u,y", comments="")
    return path


def test_pi_model_round_trip(tmp_path):
    m = pi_model()
    path = pj.save_model(tmp_path / "sub" / "m.json", m)
    keys = json.loads(path.read_text())
    assert keys["schema"] == SCHEMA and keys["structure"] == "pi"
    back = pj.load_model(path)
    assert isinstance(back, pj.HysteresisModel) and back.creep is None
    for name in ("thresholds", "weights", "initial_states"):
        np.testing.assert_array_equal(getattr(back.pi, name), getattr(m.pi, name))
    np.testing.assert_array_equal(back.offset, m.offset)
    u = 1.5 * np.sin(np.linspace(0, 12, 300))
    np.testing.assert_array_equal(back(u), m(u))


def test_operator_saves_with_zero_offset(tmp_path):
    op = pj.PIOperator(R, W, X0)
    back = pj.load_model(pj.save_model(tmp_path / "op.json", op))
    u = np.sin(np.linspace(0, 9, 200))
    np.testing.assert_array_equal(back(u), op(u))
    assert float(back.offset) == 0.0


def test_fit_saves_its_model_and_the_feedforward_agrees(tmp_path):
    import jax

    path = _record(tmp_path, noise=1e-3)
    rec = pj.load_record(path)
    fit = pj.fit_pi(rec.u, rec.y, 3, key=jax.random.key(0))
    back = pj.load_model(pj.save_model(tmp_path / "f.json", fit))
    np.testing.assert_array_equal(back(rec.u), fit(rec.u))
    yd = 0.8 * np.asarray(fit(rec.u))
    np.testing.assert_array_equal(pj.feedforward(back, yd), pj.feedforward(fit, yd))


def test_cli_fit_json_loads_and_reproduces_its_rmse(tmp_path, capsys):
    path = _record(tmp_path, noise=2e-3)
    out = tmp_path / "fitted"
    assert pj.run_cli(["fit", str(path), "--plays", "3", "--out", str(out), "--quiet"]) == 0
    report = json.loads((out / "fit.json").read_text())
    assert report["schema"] == SCHEMA and report["structure"] == "pi"
    model = pj.load_model(out / "fit.json")
    rec = pj.load_record(path)
    rmse = float(np.sqrt(np.mean((np.asarray(model(rec.u)) - rec.y) ** 2)))
    np.testing.assert_allclose(rmse, report["rmse"], rtol=1e-9)
    assert 1e-3 < rmse < 4e-3  # the noise, not a model that misses the data

    # `piest compensate` reads the same file: its feedforward equals the library's.
    t = rec.t[:200]
    desired = 0.5 * np.sin(2 * np.pi * 0.5 * t)
    np.savetxt(tmp_path / "d.csv", np.column_stack([t, desired]), delimiter=",", header="t,desired", comments="")
    ff = tmp_path / "ff"
    assert pj.run_cli(["compensate", str(out / "fit.json"), str(tmp_path / "d.csv"), "--out", str(ff), "--quiet"]) == 0
    cols = np.loadtxt(ff / "compensate.csv", delimiter=",", skiprows=1)
    np.testing.assert_allclose(cols[:, 2], np.asarray(pj.feedforward(model, desired)), rtol=0, atol=1e-12)


def test_files_without_a_schema_are_pi_models(tmp_path):
    # fit.json as `piest fit` wrote it before model files had a schema.
    old = {
        "data": "d.csv",
        "n_plays": 3,
        "thresholds": R,
        "weights": W,
        "offset": C,
        "initial_states": X0,
        "rmse": 0.01,
    }
    (tmp_path / "old.json").write_text(json.dumps(old))
    m = pj.load_model(tmp_path / "old.json")
    np.testing.assert_array_equal(m.pi.thresholds, R)
    assert float(m.offset) == C
    assert model_keys(m)["structure"] == "pi"


@pytest.mark.parametrize(
    "content, message",
    [
        ("{oops", r"not a JSON file"),
        ("[1]", r"expected a JSON object as written by `piest fit`"),
        ({"schema": SCHEMA + 1, "structure": "pi"}, rf"model file schema {SCHEMA + 1} is newer"),
        ({"schema": "1", "thresholds": R, "weights": W}, r"`schema` must be a non-negative integer"),
        (
            {"schema": 1, "structure": "neural", "thresholds": R},
            r"unknown model structure 'neural'; this piest_jax reads pi",
        ),
        ({"schema": 1, "structure": "pi", "weights": W}, r"missing thresholds"),
        # A file with a schema is written whole: a key taken out is named, not filled in.
        ({"schema": 1, "structure": "pi", "thresholds": R, "weights": W, "initial_states": X0}, r"missing offset \("),
        ({"schema": 1, "structure": "pi", "thresholds": R, "weights": W, "offset": C}, r"missing initial_states \("),
        ({"thresholds": R, "weights": W[:2]}, r"must be equal vectors"),
        ({"thresholds": R, "weights": [1.0, None, 2.0]}, r"must be finite"),
        ({"thresholds": [0.0, 0.5, 0.5], "weights": W}, r"`thresholds` must be strictly increasing"),
        (
            {"thresholds": R, "weights": W, "creep": {"time_constants": [1.0], "weights": [0.1], "dt": 0.01}},
            r"it has a `creep` but no `\"structure\": \"pi\+creep\"`",
        ),
    ],
)
def test_bad_model_files_are_refused_naming_the_file(tmp_path, content, message):
    path = tmp_path / "m.json"
    path.write_text(content if isinstance(content, str) else json.dumps(content))
    with pytest.raises(pj.DataError, match=f"^{path}: .*{message}" if not message.startswith("^") else message):
        pj.load_model(path)


def test_missing_file_and_unsaveable_models(tmp_path):
    with pytest.raises(pj.DataError, match=r"nope\.json: no such file"):
        pj.load_model(tmp_path / "nope.json")
    import equinox as eqx

    with pytest.raises(TypeError, match=r"cannot save a str; saved models are PIFit, PIOperator, HysteresisModel"):
        pj.save_model(tmp_path / "x.json", "model")
    with pytest.raises(ValueError, match=r"cannot save a model with non-finite offset"):
        pj.save_model(tmp_path / "x.json", eqx.tree_at(lambda m: m.offset, pi_model(), np.nan))
    assert not (tmp_path / "x.json").exists()


def _saturating(n=400):
    t = np.linspace(0.0, 1.0, n)
    u = 2.0 * np.sin(2 * np.pi * 4 * t) * (0.3 + 0.7 * t)
    pi = pj.PIOperator(np.array([0.0, 0.3, 0.8]), np.array([0.9, 0.5, 0.3]), u[0])
    g = pj.GeneralizedPI(pi, [1.2, 0.4], [0.1, 0.9], [1.0, 2.0], 0.3)
    return u, np.asarray(g(u)) + 1e-3 * np.random.default_rng(1).standard_normal(n)


def test_gpi_fit_round_trip_reproduces_its_rmse(tmp_path):
    u, y = _saturating()
    fit = pj.fit_gpi(u, y, 3)
    path = pj.save_model(tmp_path / "g.json", fit)
    keys = json.loads(path.read_text())
    assert keys["structure"] == "gpi" and keys["output_function"]["form"] == "tanh"
    back = pj.load_model(path)
    assert isinstance(back, pj.GeneralizedPI)
    np.testing.assert_array_equal(back(u), fit.model(u))
    rmse = float(np.sqrt(np.mean((np.asarray(back(u)) - y) ** 2)))
    np.testing.assert_allclose(rmse, float(fit.rmse), rtol=1e-9)


@pytest.mark.parametrize("initial_states", [None, 0.0])
def test_preisach_fit_round_trip_reproduces_its_rmse(tmp_path, initial_states):
    u, y = _saturating()
    fit = pj.fit_preisach(u, y, n_widths=4, n_centres=6, smoothness=1e-3, initial_states=initial_states)
    path = pj.save_model(tmp_path / "p.json", fit)
    keys = json.loads(path.read_text())
    assert keys["structure"] == "preisach" and keys["starts_at_rest"] == (initial_states is None)
    back = pj.load_model(path)
    assert isinstance(back, pj.Preisach)
    np.testing.assert_allclose(np.asarray(back(u)), np.asarray(fit.model(u)), rtol=0, atol=1e-12)
    rmse = float(np.sqrt(np.mean((np.asarray(back(u)) - y) ** 2)))
    np.testing.assert_allclose(rmse, fit.rmse, rtol=1e-7)


@pytest.mark.parametrize(
    "content, message",
    [
        (
            {"schema": 1, "structure": "gpi", "thresholds": R, "weights": W},
            r"`output_function` must hold amplitudes, centres and scales",
        ),
        (
            {
                "schema": 1,
                "structure": "gpi",
                "thresholds": R,
                "weights": W,
                "output_function": {"amplitudes": [1.0], "centres": [0.0], "scales": [-1.0]},
            },
            r"unusable output_function \(`scales` must be positive",
        ),
        (
            {
                "schema": 1,
                "structure": "gpi",
                "thresholds": R,
                "weights": W,
                "output_function": {"form": "atan", "amplitudes": [1], "centres": [0], "scales": [1]},
            },
            r"unknown output function form 'atan'",
        ),
        ({"schema": 1, "structure": "preisach", "half_widths": [0.0], "centres": [0.0, 1.0]}, r"missing blur, density"),
        (
            {
                "schema": 1,
                "structure": "preisach",
                "half_widths": [0.0],
                "centres": [0.0, 1.0],
                "blur": [0.5, 0.5],
                "density": [[1.0, 2.0, 3.0]],
            },
            r"unusable Preisach model \(`density` must have shape",
        ),
    ],
)
def test_bad_gpi_and_preisach_files_are_refused(tmp_path, content, message):
    path = tmp_path / "m.json"
    path.write_text(json.dumps(content))
    with pytest.raises(pj.DataError, match=f"^{path}: .*{message}"):
        pj.load_model(path)
