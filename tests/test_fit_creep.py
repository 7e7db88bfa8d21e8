"""Fitting PI + creep jointly, comparing with estimated initial conditions, choosing the structure."""

import jax
import numpy as np
import pytest
from test_creep import reference_lags
from test_fit import reference_pi

import piest_jax as pj

pytestmark = pytest.mark.long

R, W = np.array([0.0, 0.5, 1.2]), np.array([1.0, 0.6, 0.4])
TAU, C = np.array([0.4]), np.array([0.5])
DT, T = 0.01, 800


def plant(u, x0=None, z0=None, offset=0.3):
    x0 = u[0] if x0 is None else x0
    z0 = u[0] if z0 is None else z0
    return reference_pi(u, R, W, x0) + reference_lags(u, TAU, DT, z0) @ C + offset


def signal(T=T, phase=0.0):
    t = DT * np.arange(T)
    # Sine stretches with holds between them: creep shows while the input rests.
    s = np.sin(2 * np.pi * 0.5 * t + phase) * (1 - 0.05 * t)
    hold = (np.floor(t / 2.0) % 2) == 1
    u = 1.0 + 2.5 * s
    for i in np.flatnonzero(hold):
        u[i] = u[i - 1]
    return u


@pytest.fixture(scope="module")
def fitted():
    u = signal()
    return u, plant(u), pj.fit_pi(u, plant(u), 3, n_lags=1, dt=DT, key=jax.random.key(0))


def test_recovers_creep(fitted):
    u, y, f = fitted
    assert f.n_lags == 1 and f.model().structure == "pi+creep"
    np.testing.assert_allclose(f.creep.time_constants, TAU, rtol=1e-3)
    np.testing.assert_allclose(f.creep.weights, C, rtol=1e-3)
    np.testing.assert_allclose(f.thresholds, R, atol=1e-3)
    np.testing.assert_allclose(f.weights, W, rtol=1e-3)
    assert float(f.rmse) < 1e-4 * np.ptp(y)
    np.testing.assert_allclose(f(u), y, atol=1e-3)
    np.testing.assert_allclose(f.model()(u), f(u), rtol=1e-12)


def test_lag_weights_keep_the_sign_of_the_plays():
    # A plant whose output relaxes back (negative creep): the default fit keeps every lag weight
    # positive, so its static map increases (w_1 + sum c > 0) and it inverts; with signed
    # weights the fit recovers the plant's negative lag.
    u = signal()
    y = reference_pi(u, R, W, u[0]) + reference_lags(u, TAU, DT, u[0]) @ (-0.6 * C) + 0.3
    pos = pj.fit_pi(u, y, 3, n_lags=1, dt=DT, key=jax.random.key(0))
    assert np.all(np.asarray(pos.creep.weights) >= 0)
    assert float(pos.weights[0] + np.sum(pos.creep.weights)) > 0
    signed = pj.fit_pi(u, y, 3, n_lags=1, dt=DT, positive_weights=False, key=jax.random.key(0))
    np.testing.assert_allclose(signed.creep.weights, -0.6 * C, rtol=1e-3)
    assert float(signed.rmse) < 0.1 * float(pos.rmse)


def test_plain_pi_cannot_explain_creep(fitted):
    u, y, f = fitted
    g = pj.fit_pi(u, y, 3, key=jax.random.key(0))
    assert float(g.rmse) > 20 * float(f.rmse)


def test_compare_estimates_initial_conditions(fitted):
    # Another run of the same plant: other input, a different sensor zero, the plays and lags
    # left elsewhere by the unrecorded past. The raw prediction misses; with estimated initial
    # conditions only the admissible part of the states that matters is left.
    _, _, f = fitted
    u = signal(600, phase=1.0)
    x0 = pj.admissible_states(R, u[0] + np.array([0.0, 0.3, -0.5]))
    y = plant(u, x0=np.asarray(x0), z0=u[0] - 0.8, offset=1.0)
    raw = pj.compare(f.model().with_initial_states(u[0]), u, y, estimate_initial=False)
    ic = pj.compare(f.model().with_initial_states(u[0]), u, y)
    assert float(raw.rmse) > 0.1
    assert float(ic.rmse) < 1e-3 * np.ptp(y)
    assert float(ic.fit_percent) > 99.9
    assert abs(float(ic.model.offset) - (1.0 + (float(f.offset) - 0.3))) < 1e-2
    # The estimated play states are admissible.
    r, x = np.asarray(f.thresholds), np.asarray(ic.model.pi.initial_states)
    assert np.all(np.abs(np.diff(x)) <= np.diff(r) * (1 + 1e-12))
    # The fit percentage is the sysid formula.
    e = np.asarray(ic.prediction) - y
    np.testing.assert_allclose(ic.fit_percent, 100 * (1 - np.linalg.norm(e) / np.linalg.norm(y - y.mean())))


def test_select_model_finds_creep_when_present():
    u = signal()
    y = plant(u) + 1e-3 * np.random.default_rng(3).standard_normal(T)
    ch = pj.select_model(u, y, DT, plays=(2, 3, 4), lags=(0, 1, 2), key=jax.random.key(0))
    assert ch.structure == "pi+creep" and ch.n_lags >= 1
    scores = dict(zip(ch.candidates, ch.scores))
    assert scores[(ch.n_plays, ch.n_lags)] < 0.5 * scores[(ch.n_plays, 0)]


def test_select_model_keeps_plain_pi_without_creep():
    u = signal()
    y = reference_pi(u, R, W, u[0]) + 0.3 + 1e-3 * np.random.default_rng(4).standard_normal(T)
    ch = pj.select_model(u, y, DT, plays=(2, 3, 4), lags=(0, 1, 2), key=jax.random.key(0))
    assert ch.structure == "pi" and ch.n_lags == 0 and ch.fit.creep is None
    # One lag that does not improve does not end the search: two lags are tried as well.
    assert {(ch.n_plays, 1), (ch.n_plays, 2)} <= set(ch.candidates)


def test_bad_lag_arguments():
    u = signal(200)
    with pytest.raises(ValueError, match="time_constants0. must be positive and finite"):
        pj.fit_pi(u, plant(u[:200]), 2, n_lags=1, dt=DT, time_constants0=[-1.0])
    with pytest.raises(ValueError, match="`n_lags` must be a whole number"):
        pj.fit_pi(u, plant(u), 2, n_lags=-1, dt=DT)
    with pytest.raises(ValueError, match="`dt` must be a positive finite number"):
        pj.fit_pi(u, plant(u), 2, n_lags=1, dt=0.0)
    with pytest.raises(ValueError, match="need .* parameters"):
        pj.fit_pi(u[:8], plant(u[:8]), 2, n_lags=2, dt=DT)


def creep_model(c=C):
    return pj.HysteresisModel(pj.PIOperator(R, W, 1.0), pj.Creep(TAU, c, DT), 0.3)


@pytest.mark.parametrize("c", [C, -0.3 * C, np.array([0.5, -0.2])])
def test_feedforward_inverts_pi_plus_creep(c, rng):
    # model(feedforward(model, y_d)) == y_d for any target, creep of either sign included.
    tau = TAU if len(c) == 1 else np.array([0.1, 2.0])
    m = pj.HysteresisModel(pj.PIOperator(R, W, 1.0), pj.Creep(tau, c, DT), 0.3)
    yd = 1.0 + np.cumsum(rng.standard_normal(400)) * 0.1
    u = pj.feedforward(m, yd)
    np.testing.assert_allclose(m.with_initial_states(1.0)(u), yd, atol=1e-9)
    # The forward model started at rest at u_0 is the NumPy reference with the same states.
    ref = reference_pi(np.asarray(u), R, W, 1.0) + reference_lags(np.asarray(u), tau, DT, u[0]) @ c + 0.3
    np.testing.assert_allclose(ref, yd, atol=1e-9)


def test_feedforward_refuses_non_invertible():
    m = pj.HysteresisModel(pj.PIOperator(R, W, 1.0), pj.Creep([0.001], [-5.0], DT), 0.3)
    with pytest.raises(ValueError, match="weight"):
        pj.feedforward(m, np.ones(10))


def test_creep_compensation_beats_pi_only(fitted):
    # A plant with creep, tracked with the inverse of a fitted PI + creep and of a fitted PI.
    u, y, f = fitted
    pi_only = pj.fit_pi(u, y, 3, key=jax.random.key(0))
    t = DT * np.arange(600)
    yd = plant(u)[0] + 2.0 * np.sin(2 * np.pi * 0.3 * t) ** 2

    def run(uu):
        return plant(np.asarray(uu), x0=1.0, z0=np.asarray(uu)[0])

    with_creep = pj.evaluate_compensation(run, f.model().with_initial_states(1.0), yd)
    without = pj.evaluate_compensation(run, pi_only.model().with_initial_states(1.0), yd)
    assert float(with_creep.rmse_compensated) < 0.01 * float(without.rmse_compensated)
    assert float(without.rmse_compensated) < float(without.rmse_linear)


def write_record(path, u, y, dt=DT):
    t = np.arange(len(u)) * dt
    np.savetxt(path, np.column_stack([t, u, y]), delimiter=",", header="t,u,y", comments="")


def test_cli_fit_and_compensate_with_creep(tmp_path, capsys):
    import json

    from piest_jax._cli import main

    u = signal()
    write_record(tmp_path / "d.csv", u, plant(u))
    uv = signal(600, phase=1.0)
    write_record(tmp_path / "v.csv", uv, plant(uv, offset=0.8))
    out = tmp_path / "out"
    rc = main(
        [
            "fit",
            str(tmp_path / "d.csv"),
            "--model",
            "pi+creep",
            "--plays",
            "3",
            "--lags",
            "1",
            "--validate",
            str(tmp_path / "v.csv"),
            "--out",
            str(out),
            "--quiet",
        ]
    )
    assert rc == 0
    capsys.readouterr()
    rep = json.loads((out / "fit.json").read_text())
    assert rep["model"] == {"structure": "pi+creep", "n_plays": 3, "n_lags": 1}
    np.testing.assert_allclose(rep["creep"]["time_constants"], TAU, rtol=1e-3)
    np.testing.assert_allclose(rep["creep"]["weights"], C, rtol=1e-3)
    assert rep["creep"]["starts_at_rest"] and "initial_states" not in rep["creep"]
    assert rep["creep"]["dt"] == pytest.approx(DT)
    for key in ("thresholds", "weights", "offset", "initial_states", "rmse", "flagged", "solver"):
        assert key in rep
    # The validation run has another sensor zero (+0.5): raw misses by it, the estimated
    # offset takes it out.
    assert rep["validation_rmse"] == pytest.approx(0.5, rel=1e-2)
    assert rep["validation_rmse_ic"] < 1e-3
    assert rep["validation_fit_percent"] > 99.9
    # fit.json is a model file: load_model gives the PI + creep model back, and its output on the
    # identification record reproduces the reported RMSE; save_model writes the same keys.
    assert rep["schema"] == 1 and rep["structure"] == "pi+creep"
    model = pj.load_model(out / "fit.json")
    assert isinstance(model, pj.HysteresisModel) and model.structure == "pi+creep"
    y_fit = plant(u)
    rmse = float(np.sqrt(np.mean((np.asarray(model(u)) - y_fit) ** 2)))
    assert rmse == pytest.approx(rep["rmse"], rel=1e-6, abs=1e-12)
    again = pj.load_model(pj.save_model(tmp_path / "again.json", model))
    np.testing.assert_allclose(np.asarray(again(u)), np.asarray(model(u)), rtol=0, atol=1e-12)
    # piest compensate reads the creep and inverts PI + creep.
    t = DT * np.arange(300)
    yd = plant(u)[0] + 1.5 * np.sin(2 * np.pi * 0.4 * t) ** 2
    np.savetxt(tmp_path / "yd.csv", np.column_stack([t, yd]), delimiter=",", header="t,desired", comments="")
    rc = main(["compensate", str(out / "fit.json"), str(tmp_path / "yd.csv"), "--out", str(tmp_path / "ff"), "--quiet"])
    assert rc == 0
    data = np.loadtxt(tmp_path / "ff" / "compensate.csv", delimiter=",", skiprows=1)
    x0 = np.asarray(pj.admissible_states(rep["thresholds"], rep["initial_states"]))
    ref = (
        reference_pi(data[:, 2], np.asarray(rep["thresholds"]), np.asarray(rep["weights"]), x0)
        + reference_lags(data[:, 2], rep["creep"]["time_constants"], DT, data[0, 2])
        @ np.asarray(rep["creep"]["weights"])
        + rep["offset"]
    )
    np.testing.assert_allclose(ref, yd, atol=1e-8)
    np.testing.assert_allclose(data[:, 3], yd, atol=1e-8)


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--time-constants", "-1"], "is not positive"),
        (["--time-constants", "0.001"], "shorter than the sampling interval"),
        (["--time-constants", "1e6"], "over 100 times the record's duration"),
        (["--model", "pi", "--time-constants", "1"], "needs --model pi+creep"),
        (["--criterion", "bic"], "use it with --model pi"),
    ],
)
def test_cli_fit_refuses_bad_creep(tmp_path, capsys, extra, message):
    from piest_jax._cli import main

    u = signal(200)
    write_record(tmp_path / "d.csv", u, plant(u))
    out = tmp_path / "out"
    assert main(["fit", str(tmp_path / "d.csv"), *extra, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_cli_fit_refuses_unknown_model(tmp_path, capsys):
    from piest_jax._cli import main

    u = signal(200)
    write_record(tmp_path / "d.csv", u, plant(u))
    with pytest.raises(SystemExit) as exc:
        main(["fit", str(tmp_path / "d.csv"), "--model", "creep-pi", "--out", str(tmp_path / "o")])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "invalid choice: 'creep-pi'" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "o").exists()


def test_residual_gradient_with_lags_matches_finite_differences():
    # The fit differentiates through the joint play and lag scan; central differences check it.
    import jax.flatten_util
    import jax.numpy as jnp

    from piest_jax._identification import fit as _fit

    u = signal(200)
    y = plant(u)
    un = jnp.asarray((u - u.mean()) / np.ptp(u))
    yn = jnp.asarray((y - y.mean()) / np.ptp(y))
    params = {
        "increments": jnp.asarray([-1.0, -0.7]),
        "weights": jnp.asarray([0.3, -0.2, 0.5]),
        "offset": jnp.asarray(0.1),
        "lag_theta": jnp.asarray([1.5, 0.3]),
        "lag_weights": jnp.asarray([0.4, -0.3]),
        "lag_states": jnp.asarray([0.05, -0.1]),
    }
    args = (
        un,
        yn,
        jnp.zeros(3),
        jnp.ones(200),
        True,
        None,
        None,
        jnp.zeros(2),
        None,
        jnp.log(jnp.asarray([2.0, 2.0 * np.sqrt(10.0)])),
    )

    @jax.jit
    def loss(p):
        return jnp.sum(_fit._residuals(p, args) ** 2)

    flat, unravel = jax.flatten_util.ravel_pytree(params)
    g = jax.flatten_util.ravel_pytree(jax.grad(loss)(params))[0]
    eps = 1e-6
    fd = np.array(
        [
            (loss(unravel(flat.at[i].add(eps))) - loss(unravel(flat.at[i].add(-eps)))) / (2 * eps)
            for i in range(flat.shape[0])
        ]
    )
    np.testing.assert_allclose(g, fd, rtol=1e-5, atol=1e-9)


def test_creep_only_search_chooses_the_plays_without_creep():
    # With only creep models offered, the play count is still chosen for the plain PI model: a lag
    # fitted alongside one play takes over part of the loops, and the search would stop there.
    u = signal()
    y = plant(u) + 1e-3 * np.random.default_rng(3).standard_normal(T)
    ch = pj.select_model(u, y, DT, plays=(1, 2, 3), lags=(1,), key=jax.random.key(0))
    plain = [c[0] for c in ch.candidates if c[1] == 0]
    assert plain == [1, 2, 3][: len(plain)] and ch.n_plays in plain
    assert ch.structure == "pi+creep" and ch.n_lags == 1 and ch.n_plays == len(R)
    assert all(c[1] in (0, 1) for c in ch.candidates)


def test_creep_search_walks_the_play_count_down_beside_a_lag():
    # Two plays and a lag. Without creep, more plays imitate the creep (the plain search keeps 3);
    # beside the lag the extra play keeps almost no weight and its threshold is free. The search
    # walks the play count down with the lag until the record determines every parameter.
    r, w = np.array([0.0, 0.8]), np.array([1.0, 0.5])
    u = signal()
    y = reference_pi(u, r, w, u[0]) + reference_lags(u, TAU, DT, u[0]) @ C + 0.3
    y = y + 1e-3 * np.random.default_rng(3).standard_normal(T)
    ch = pj.select_model(u, y, DT, plays=(1, 2, 3, 4), lags=(0, 1, 2), key=jax.random.key(0))
    one_lag = [c for c in ch.candidates if c[1] == 1]
    assert one_lag == [(3, 1), (2, 1)] and (3, 1) in ch.rejected
    assert (ch.n_plays, ch.n_lags) == (2, 1) and ch.fit.determined


def test_what_the_record_determines_is_judged_on_all_of_it():
    # The second play moves only in the held-out block: fitted before it, its threshold and weight
    # are free; fitted on the whole record, determined. The candidate is not rejected.
    n = 1000
    t = np.arange(n) / n
    u = np.where(t < 0.7, 0.3, 2.5) * np.sin(2 * np.pi * 8 * t)
    y = reference_pi(u, np.array([0.0, 0.5]), np.array([1.0, 0.6]), 0.0)
    y = y + 1e-3 * np.random.default_rng(0).standard_normal(n)
    opts = dict(key=jax.random.key(0), initial_states=0.0)
    part = np.zeros(n)
    part[: round(0.7 * n)] = 1.0
    assert not pj.fit_pi(u, y, 2, mask=part, pad_plays=2, **opts).determined
    assert pj.fit_pi(u, y, 2, pad_plays=2, **opts).determined
    # (With no tolerance, so that its small gain counts: one that could not be chosen anyway is
    # not judged again.)
    a = pj.select_plays(u, y, (1, 2), patience=None, tolerance=0.0, **opts)
    b = pj.select_model(u, y, 1.0 / n, (1, 2), (0,), tolerance=0.0, **opts)
    assert a.candidates == (1, 2) and a.rejected == () and a.scores[1] < a.scores[0]
    assert b.candidates == ((1, 0), (2, 0)) and b.rejected == ()
