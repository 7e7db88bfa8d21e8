"""Standard errors of a diagnosis's effect parameters (`_diagnosis/uncertainty.py`)."""

import jax
import jax.flatten_util
import numpy as np
import pytest

import piest_jax as pj
from piest_jax._diagnosis import diagnose as _diagnose
from piest_jax._diagnosis import hidden as _hidden
from piest_jax._diagnosis import refine as _refine
from piest_jax._diagnosis import uncertainty as _unc
from piest_jax._diagnosis.scaling import prepared, scaling_of


@pytest.fixture(scope="module")
def delayed():
    rec, _ = _hidden.generate(("delay",), key=jax.random.PRNGKey(100), n_samples=500)
    return rec, _diagnose.search(rec, max_effects=1, candidates=["delay"])


def test_the_jacobian_is_the_models_derivative(delayed):
    # Forward-mode derivative through the scans against central differences of the model.
    rec, s = delayed
    sc = scaling_of(rec)
    p = prepared(rec, sc)
    entry = s["model_final"]
    theta, st, _ = _unc.parameters(entry)
    data, y, _ = _refine.data_of(p, entry["norm"], pad=False)
    flat, unravel = jax.flatten_util.ravel_pytree(theta)
    J, e = _unc._jacobian(flat, unravel, st, data, y)
    np.testing.assert_allclose(e, _refine.model(theta, st, data) - y, rtol=1e-12, atol=1e-14)
    for i in range(flat.shape[0]):
        h = 1e-6 * max(1.0, abs(float(flat[i])))
        up = _refine.model(unravel(flat.at[i].add(h)), st, data)
        down = _refine.model(unravel(flat.at[i].add(-h)), st, data)
        np.testing.assert_allclose(J[:, i], (up - down) / (2 * h), rtol=1e-5, atol=1e-7)


def test_without_the_errors_the_search_is_the_same(delayed):
    rec, s = delayed
    quick = _diagnose.search(rec, max_effects=1, candidates=["delay"], uncertainty=False)
    assert quick["uncertainty"] is None and s["uncertainty"] is not None
    assert quick["effects"] == s["effects"] == ["delay"]
    assert quick["model_final"]["cfg"] == s["model_final"]["cfg"]
    np.testing.assert_array_equal(quick["model_final"]["coef"], s["model_final"]["coef"])


def test_the_report_gives_the_named_effects_errors(delayed):
    rec, s = delayed
    u = s["uncertainty"]
    assert u["method"] == "newey-west" and u["samples"] == rec.n_samples
    assert list(u["values"]) == ["delay.delay_s", "offset"]
    assert u["values"]["delay.delay_s"] == pytest.approx(
        pj.diagnose(rec, max_effects=1, candidates=["delay"]).parameters["delay"]["delay_s"], rel=1e-9
    )
    # A delay of a few samples on a 500-sample record is known to a fraction of a sample.
    dt = float(np.median(np.diff(rec.t)))
    se = u["std_errors"]["delay.delay_s"]
    assert 0 < se < 0.2 * dt and u["undetermined"] == []
    # The offset in the output's units: its error is about the noise over the root of the samples
    # (a few times that for coloured residuals), far below the output's range.
    assert 0 < u["std_errors"]["offset"] < 0.01 * np.ptp(rec.y)


def test_a_direction_the_record_leaves_free_is_undetermined(delayed, monkeypatch):
    # The same model with the delay's derivative removed (the delay read through a stop gradient):
    # the Jacobian's column is zero, so the delay is undetermined, not given a small error.
    rec, s = delayed
    sc = scaling_of(rec)
    p = prepared(rec, sc, step=3)  # a length no other test traces the Jacobian at
    entry = s["model_final"]
    keys = [k for k in _unc.parameters(entry)[0] if "delay" in k]
    assert keys

    def model(theta, st, data, **kw):
        theta = {k: (jax.lax.stop_gradient(v) if k in keys else v) for k, v in theta.items()}
        return _refine.model(theta, st, data, **kw)

    monkeypatch.setattr(_unc, "model", model)
    u = _unc.parameter_uncertainty(p, entry, sc)
    assert u["std_errors"]["delay.delay_s"] is None and "delay.delay_s" in u["undetermined"]
    assert u["std_errors"]["offset"] is not None and "offset" not in u["undetermined"]


def test_no_effect_no_uncertainty():
    rec, _ = _hidden.generate((), key=jax.random.PRNGKey(101), n_samples=400)
    d = pj.diagnose(rec, candidates=["delay"], max_effects=1, solver=None)
    assert d.effects == [] and d.uncertainty is None and "uncertainty" not in d
