"""The effects' regressors against plain references: play loop, history states, delay by
interpolation, filters against a fine-step ODE solution, low-pass loop, constrained least squares
against scipy's NNLS, blocked cross-validation against an explicit loop."""

from types import SimpleNamespace

import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import optimize

from piest_jax import play
from piest_jax._data.record import Record
from piest_jax._diagnosis import basis as _basis
from piest_jax._diagnosis import model as _model
from piest_jax._diagnosis import output_map as _output_map
from piest_jax._diagnosis.effects import EFFECT
from piest_jax._diagnosis.effects import asymmetry as _asymmetry
from piest_jax._diagnosis.effects import creep as _creep
from piest_jax._diagnosis.effects import delay as _delay
from piest_jax._diagnosis.effects import linear_dynamics as _linear_dynamics
from piest_jax._diagnosis.effects import offset_drift as _offset_drift
from piest_jax._diagnosis.effects import saturation as _saturation
from piest_jax._diagnosis.scaling import N_BLOCKS, N_FOLDS, Prepared, prepared, scaling_of
from piest_jax._identification.time_constants import LAG_RATIO, shortest_time_constant


def _loop_plays(g, r, x0):
    x = np.array(x0, float)
    out = []
    for i, gi in enumerate(g):
        ri = r if np.ndim(r) == 1 else r[i]
        x = np.array([max(gi - rj, min(gi + rj, xj)) for xj, rj in zip(x, ri)])
        out.append(x)
    return np.array(out)


def _record(n=400, seed=0, dt=0.01):
    rng = np.random.default_rng(seed)
    t = np.arange(n) * dt
    u = 0.8 * np.sin(2 * np.pi * 0.7 * t) * np.minimum(t, 1) + 0.2 * np.sin(2 * np.pi * 2.3 * t)
    y = rng.normal(size=n)
    folds = np.minimum(np.arange(n) * 16 // n, 15) % 4
    return Prepared(u, y, t, rate_scale=5.0, period=1 / 0.7, folds=folds)


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 10_000))
def test_plays_match_a_loop_and_the_play_operator(seed):
    rng = np.random.default_rng(seed)
    g = np.cumsum(rng.normal(size=60)) * 0.2
    x0 = rng.uniform(-1, 1, size=(2, _basis.N_PLAYS))
    out = _basis.plays(g, _basis.THRESHOLDS, x0)
    for c in range(2):
        np.testing.assert_allclose(out[c], _loop_plays(g, _basis.THRESHOLDS, x0[c]), atol=1e-14)
    rt = _basis.THRESHOLDS[None, :] * (1 + rng.uniform(0, 1, size=(60, 1)))
    np.testing.assert_allclose(_basis.plays(g, rt, x0[:1])[0], _loop_plays(g, rt, x0[0]), atol=1e-14)
    relaxed = _basis.plays(g, _basis.THRESHOLDS, np.full((1, _basis.N_PLAYS), g[0]))[0]
    np.testing.assert_allclose(relaxed, np.asarray(play(g, _basis.THRESHOLDS, g[0])), atol=1e-12)


@pytest.mark.parametrize("u0, a", [(0.0, 0.7), (0.2, -0.5), (-0.3, 1.9)])
def test_history_states_of_one_excursion(u0, a):
    r = _basis.THRESHOLDS
    x = _basis.history_states(u0, (a,))
    # Up (down) to a leaves max(u0, a - r) (min(u0, a + r)); back at u0 the play is clamped to u0 +- r.
    s = np.sign(a - u0)
    expect = u0 + s * np.minimum(np.maximum(abs(a - u0) - r, 0.0), r)
    np.testing.assert_allclose(x, expect, atol=1e-14)
    assert np.all(np.abs(x - u0) <= r + 1e-14)  # admissible states


@pytest.mark.parametrize("d", [0.0, 3.0, 2.4, 0.3])
def test_delay_is_interpolation(d):
    X = np.column_stack([np.sin(np.arange(50) * 0.3), np.arange(50.0) ** 1.5])
    idx = np.arange(50.0)
    ref = np.column_stack([np.interp(idx - d, idx, X[:, j], left=X[0, j]) for j in range(2)])
    np.testing.assert_allclose(_delay.delayed(X, d), ref, atol=1e-12)


def _ode_reference(v, dt, spec, sub=400):
    """A fine-step RK4 solution with the input linear between samples, started at rest at v0."""
    if spec[0] == "first":
        f = lambda x, vv: np.array([(vv - x[0]) / spec[1]])  # noqa: E731
        x = np.array([v[0]])
    else:
        w, z = spec[1], spec[2]
        f = lambda x, vv: np.array([x[1], w * w * (vv - x[0]) - 2 * z * w * x[1]])  # noqa: E731
        x = np.array([v[0], 0.0])
    h, out = dt / sub, [x[0]]
    for k in range(1, len(v)):
        for i in range(sub):
            va, vm, vb = (v[k - 1] + (v[k] - v[k - 1]) * (i + c) / sub for c in (0, 0.5, 1))
            k1 = f(x, va)
            k2 = f(x + h / 2 * k1, vm)
            k3 = f(x + h / 2 * k2, vm)
            k4 = f(x + h * k3, vb)
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        out.append(x[0])
    return np.array(out)


@pytest.mark.parametrize("spec", [("first", 0.03), ("first", 0.004), ("second", 40.0, 0.3), ("second", 150.0, 0.9)])
def test_dynamics_match_the_ode(spec):
    dt = 0.01
    v = np.concatenate([np.zeros(5), np.sin(np.arange(40) * 0.4)])
    got = _linear_dynamics.dynamics(v[:, None], spec, dt)[:, 0]
    np.testing.assert_allclose(got, _ode_reference(v, dt, spec), atol=1e-8)
    step = _linear_dynamics.dynamics(np.ones((300, 1)) * 2.0, spec, dt)[:, 0]
    np.testing.assert_allclose(step, 2.0, atol=1e-12)  # at rest and unit gain


def test_lowpass_matches_a_loop():
    v = np.sin(np.arange(30) * 0.5)
    lam = np.array([0.5, 0.9])
    ref = np.empty((30, 2))
    s = np.full(2, v[0])
    for i in range(30):
        s = lam * s + (1 - lam) * v[i]
        ref[i] = s
    np.testing.assert_allclose(_creep.lowpass(v, lam), ref, atol=1e-14)


def test_least_squares_keeps_play_weights_positive_and_matches_nnls():
    rng = np.random.default_rng(1)
    p = _record()
    H = p.plain_plays()
    A = np.column_stack([H, np.ones(len(H)), rng.normal(size=len(H))])
    y = H @ np.where(np.arange(_basis.N_PLAYS) % 3 == 0, 0.5, 0.0) - 0.3 * A[:, -1] + 0.01 * rng.normal(size=len(H))
    w = _model.lstsq(A, y)
    assert np.all(w[: _basis.N_PLAYS] >= 0)
    # Reference: scipy's NNLS with the free columns split into positive and negative parts.
    k = _basis.N_PLAYS
    z = optimize.nnls(np.column_stack([A, -A[:, k:]]), y)[0]
    ref = np.concatenate([z[:k], z[k : A.shape[1]] - z[A.shape[1] :]])
    np.testing.assert_allclose(A @ w, A @ ref, atol=1e-4)


def test_fit_recovers_a_noise_free_delayed_pi():
    p = _record()
    w_true = np.linspace(1.0, 0.1, _basis.N_PLAYS)
    cfg = {"delay": 0.023}
    X = _model.linear_part(p, cfg)
    p.y = X[:, :-1] @ w_true + 0.4
    f = _model.fit(p, cfg)
    np.testing.assert_allclose(f.A @ f.w, p.y, atol=1e-5)
    np.testing.assert_allclose(_model.predict(p, cfg, f.w, f.w_v, f.norm), f.A @ f.w, atol=1e-12)
    # Without the delay the same data leave a clear misfit.
    f0 = _model.fit(p, {})
    assert np.sqrt(np.mean((f0.A @ f0.w - p.y) ** 2)) > 1e-3


def test_output_polynomial_reaches_the_nonlinear_optimum():
    # y = v + a v^2 + b (tanh(3 v) / 3 - v) with v a PI output: Gauss-Newton steps reach an
    # exact fit, which a fixed-point iteration on the output map's columns does not. The even
    # power is the asymmetry's, the odd saturating term the saturation's: together they fit it.
    p = _record()
    v = _basis.plays(p.u, _basis.THRESHOLDS, np.full((1, 16), p.u[0]))[0] @ np.linspace(0.3, 0.02, 16)
    vn = (v - 0.5 * (v.max() + v.min())) / (0.5 * np.ptp(v))
    p.y = vn + 0.3 * vn**2 + 0.2 * (np.tanh(3.0 * vn) / 3.0 - vn)
    cfg = {"asymmetry": 0.0, "saturation": _saturation.NONE}
    f = _model.fit(p, cfg)
    pred = _model.predict(p, cfg, f.w, f.w_v, f.norm)
    assert np.sqrt(np.mean((pred - p.y) ** 2)) < 1e-4
    np.testing.assert_allclose(f.A @ f.w - f.target, pred - p.y, atol=1e-4)  # linearised = model


@pytest.mark.parametrize("name,part", [("asymmetry", "even"), ("saturation", "odd")])
def test_asymmetry_and_saturation_split_the_output_map(name, part):
    # An odd output map keeps the loop point-symmetric and an even one breaks it: each effect
    # fits its own part of a memoryless output map exactly, and leaves the other part.
    p = _record()
    v = _basis.plays(p.u, _basis.THRESHOLDS, np.full((1, 16), p.u[0]))[0] @ np.linspace(0.3, 0.02, 16)
    vn = (v - 0.5 * (v.max() + v.min())) / (0.5 * np.ptp(v))
    even = 0.25 * vn**2 - 0.1 * vn**4
    odd = 0.3 * (np.tanh(3.0 * vn) / 3.0 - vn)

    cfg = {name: 0.0 if name == "asymmetry" else _saturation.NONE}  # output terms only

    def misfit(y):
        p.y = y
        f = _model.fit(p, cfg)
        return np.sqrt(np.mean((_model.predict(p, cfg, f.w, f.w_v, f.norm) - y) ** 2))

    own, other = (even, odd) if part == "even" else (odd, even)
    # The other part is not fitted: a plain PI fit leaves it, and so does the effect (within 20 %).
    p.y = vn + other
    X = _model.linear_part(p, {})
    plain = np.sqrt(np.mean((X @ _model.lstsq(X, p.y) - p.y) ** 2))
    assert plain > 3e-3 and misfit(vn + other) > 0.8 * plain
    # Its own part it fits to a hundredth of that (the centre the powers are taken about is
    # the fitted hysteresis output's, not the plain fit's, which an even part shifts).
    assert misfit(vn + own) < 0.01 * plain


@pytest.mark.parametrize("name", ["asymmetry", "saturation"])
def test_synthetic_output_maps_have_their_effects_symmetry(name):
    # The generator's forms are pure: asymmetry's output maps are even about the loop's centre
    # (beyond the identity), saturation's odd and flattening; both are monotone.
    e = EFFECT[name]
    v = np.linspace(-3.0, 5.0, 801)  # centre 1, half-range 4
    z = (v - 1.0) / 4.0
    ctx = SimpleNamespace(amp=1.0)
    for seed in range(40):
        state = e.draw(np.random.default_rng(seed), ctx)
        new, y = e.synth_output(state, ctx, v, v.copy())
        np.testing.assert_array_equal(new, y)
        assert np.all(np.diff(new) > 0), state
        extra = (new - 1.0) / 4.0 - z
        if name == "asymmetry":
            np.testing.assert_allclose(extra, extra[::-1], atol=1e-12)
        else:
            np.testing.assert_allclose(new - 1.0, -(new - 1.0)[::-1], atol=1e-12)
            if "output" in state["form"]:
                # Flattening: the ends keep their place, the slope falls towards them.
                np.testing.assert_allclose(new[[0, -1]], v[[0, -1]], atol=1e-12)
                slope = np.diff(new)
                assert slope[-1] < slope[len(slope) // 2], state


def test_saturating_terms_follow_saturation_curves_where_odd_powers_do_not():
    # With the linear term, the two tanh terms follow each synthetic output saturation, at the
    # ends of its strength range, to 0.1 % of the range (RMS); the odd powers v^3, v^5 leave
    # more than 1 % of the strongest (the docs' numbers).
    z = np.linspace(-1.0, 1.0, 401)
    ctx = SimpleNamespace(amp=1.0)
    worst = {"tanh": 0.0, "powers": 0.0}
    for form, strengths in _saturation.STRENGTH_RANGES.items():
        if not form.startswith("output"):
            continue
        for k in strengths:
            curve, _ = EFFECT["saturation"].synth_output({"form": form, "k": k}, ctx, z, z.copy())
            for name, cols in (
                ("tanh", _output_map.saturating(z, (0.0, 1.0), _saturation.RATES)),
                ("powers", _output_map.powers(z, (0.0, 1.0), (3, 5))),
            ):
                A = np.column_stack([z, np.ones_like(z), cols])
                res = A @ np.linalg.lstsq(A, curve, rcond=None)[0] - curve
                worst[name] = max(worst[name], np.sqrt(np.mean(res**2)) / np.ptp(curve))
    assert worst["tanh"] < 1e-3 < 1e-2 < worst["powers"], worst


def test_saturation_envelope_is_a_centred_tanh():
    g = np.linspace(-1.0, 1.0, 201)
    for k in _saturation.STRENGTHS:
        out = _saturation.envelope(g, k)
        np.testing.assert_allclose(out[[0, 100, -1]], [-1.0, 0.0, 1.0], atol=1e-15)
        assert np.all(np.diff(out) > 0)
        for c in _saturation.CENTRES:
            ref = np.tanh(k * (g - c)) / np.tanh(k)
            np.testing.assert_allclose(_saturation.envelope(g, k, c), ref, rtol=1e-14)
            np.testing.assert_allclose(
                np.asarray(_saturation.envelope(jnp.asarray(g), jnp.asarray(k), c, jnp)), ref, rtol=1e-12
            )
    assert _saturation.envelope(g, 0.0) is g


def test_output_side_effects_are_reproduced_by_predict():
    p = _record()
    cfg = {"creep": _creep.Lags((0.5, 5.0), "output"), "offset_drift": True}
    p.y = np.tanh(1.5 * _basis.plays(p.u, _basis.THRESHOLDS, np.zeros((1, 16)))[0] @ np.full(16, 0.1))
    f = _model.fit(p, cfg)
    assert f.A.shape[1] == _basis.N_PLAYS + 1 + 2 + _offset_drift.N_DRIFT
    np.testing.assert_allclose(_model.predict(p, cfg, f.w, f.w_v, f.norm), f.A @ f.w, atol=1e-12)
    cfg = {"asymmetry": 0.2, **cfg}
    f = _model.fit(p, cfg)
    pos = _model.positive_mask(cfg, f.A.shape[1])
    # Plays and the two creep lags of the output are sign-constrained; offset, polynomial and
    # drift are free, and so are lags of the input.
    assert pos.sum() == _basis.N_PLAYS + 2 and pos[_basis.N_PLAYS + 1 + len(_asymmetry.POWERS)]
    assert np.all(f.w[pos] >= 0)
    cfg = {**cfg, "creep": _creep.Lags((0.5, 5.0), "input", 0.1)}
    pos = _model.positive_mask(cfg, _model.fit(p, cfg).A.shape[1])
    assert pos.sum() == _basis.N_PLAYS and not pos[_basis.N_PLAYS + 1 + len(_asymmetry.POWERS)]


def test_cross_validation_matches_an_explicit_loop():
    p = _record()
    A = np.column_stack([p.plain_plays(), np.ones(len(p.y))])
    mse, err = _model.cv_mse(p, A)
    ref = np.empty(len(p.y))
    for k in range(4):
        te = p.folds == k
        ref[te] = p.y[te] - A[te] @ _model.lstsq(A[~te], p.y[~te])
    np.testing.assert_allclose(err, ref, atol=1e-9)
    assert mse == pytest.approx(np.mean(ref**2))


def test_the_first_block_is_in_no_fold():
    t = np.arange(6400) * 1e-3
    rec = Record(t, np.sin(2 * np.pi * 3 * t), np.sin(2 * np.pi * 3 * t - 0.3))
    for step in (1, 3):
        p = prepared(rec, scaling_of(rec), step=step, folds=True)
        first = np.arange(len(p.u)) < len(p.u) / N_BLOCKS
        assert np.all(p.folds[first] == -1) and set(p.folds[~first]) == set(range(N_FOLDS))


def test_cross_validation_always_fits_the_first_block():
    # Fold -1 (the record's start, where the unrecorded past acts) is in every fit and in no
    # score: its errors are NaN and the MSE is that of the held-out folds.
    p = _record()
    start = np.arange(len(p.y)) < len(p.y) // 16
    p.folds = np.where(start, -1, p.folds)
    p.y = p.y + np.where(start, 5.0, 0.0)  # a start far off every model, as a transient is
    A = np.column_stack([p.plain_plays(), np.ones(len(p.y))])
    mse, err = _model.cv_mse(p, A)
    ref = np.full(len(p.y), np.nan)
    pos = _model.positive_mask({}, A.shape[1])
    for k in range(4):
        te, tr = p.folds == k, p.folds != k
        # The column scale of the whole design, as cv_mse's folds share it (the weak ridge
        # depends on it): the start's offset of 5 moves it.
        w = _model._solve(A[tr].T @ A[tr], A[tr].T @ p.y[tr], _model._scale(A), pos)
        ref[te] = p.y[te] - A[te] @ w
    np.testing.assert_allclose(err, ref, atol=1e-9)
    assert np.all(np.isnan(err[start])) and mse == pytest.approx(np.mean(ref[~start] ** 2))


def test_grids_and_refinements_are_physical():
    p = _record()
    assert all(d > 0 for d in EFFECT["delay"].grid(p))
    assert all(q[1] > 0 for q in EFFECT["linear_dynamics"].grid(p))
    for turns in EFFECT["initial_state"].grid(p):
        x = _basis.history_states(p.u[0], turns)
        assert np.all(np.abs(x - p.u[0]) <= _basis.THRESHOLDS + 1e-12)
    # Creep: one bank of lags of the output up to the record's length, and lags of the input
    # that keep the bounds of `piest fit`'s creep (none faster than the input's reversals
    # allow, each at least LAG_RATIO slower than the one before), as do their neighbours.
    out, *inp = EFFECT["creep"].grid(p)
    assert out.drive == "output" and len(out) == _creep.N_OUTPUT_MODES
    assert out[-1] == pytest.approx(p.t[-1] - p.t[0]) and EFFECT["creep"].neighbours(out, 0) == []
    lo = shortest_time_constant(p.u, p.dt)
    assert len(inp) == _creep.N_STARTS
    for taus in inp:
        assert taus.drive == "input" and len(taus) == _creep.N_INPUT_LAGS and taus.shortest == lo
        assert taus[0] > lo and np.all(np.diff(np.log(taus)) >= np.log(LAG_RATIO) - 1e-12)
        near = EFFECT["creep"].neighbours(taus, 0)
        assert near and all(n[0] >= lo and np.all(np.diff(np.log(n)) >= np.log(LAG_RATIO) - 1e-12) for n in near)
    # Near the fastest bound, the two moves below it (the fastest lag alone, all lags together)
    # are left out and the other six kept.
    near = EFFECT["creep"].neighbours(_creep.Lags((lo * 1.01, lo * 10, lo * 100), "input", lo), 0)
    assert len(near) == 6 and all(n[0] > lo for n in near)
    q = ("second", 100.0, 0.5)
    assert all(n[1] > 0 and 0 < n[2] <= 1.5 for n in EFFECT["linear_dynamics"].neighbours(q, 0))


@pytest.mark.parametrize("form", ["linear", "two_bands", "four_bands", "eight_bands"])
def test_noncongruence_terms_are_a_preisach_density_that_depends_on_the_centre(form):
    # Relays of half-width r centred on a fine grid of s, weighted by a density f(s) and switched
    # by the input: those centred below the play's output x_r are up, so their weighted sum is
    # 2 G(x_r) - G(S) - G(-S) with G' = f. A density linear in the centre, f = 1 + a s, has
    # G = x + a x^2 / 2; one that steps by a_k at s_k has G = x + sum_k a_k (x - s_k)+. The
    # effect's columns for that play carry G exactly.
    from piest_jax._diagnosis.effects import minor_loop_noncongruence as _mlnc

    rng = np.random.default_rng(0)
    g = np.cumsum(rng.normal(size=300))
    g = 0.9 * (g - g.mean()) / np.abs(g - g.mean()).max()
    H = _basis.plays(g, _basis.THRESHOLDS, np.full((1, _basis.N_PLAYS), g[0]))[0]
    cols = EFFECT["minor_loop_noncongruence"].play_terms(form, H)
    n = len(_mlnc.PLAYS)
    S, ds = 2.0, 1e-4
    s = np.arange(-S, S, ds) + ds / 2
    edges = _mlnc.FORMS[form]
    if edges is None:
        a = np.array([0.35])
        f = 1 + a[0] * s
        G = lambda x: x + a[0] * x**2 / 2  # noqa: E731
        coef = a / 2
    else:
        a = np.array([0.5, -0.3, 0.4, -0.2, 0.3, -0.4, 0.25])[: len(edges)]
        f = 1 + sum(ak * (s > sk) for ak, sk in zip(a, edges))
        G = lambda x: x + sum(ak * np.maximum(x - sk, 0) for ak, sk in zip(a, edges))  # noqa: E731
        coef = a
    assert cols.shape == (300, len(coef) * n)
    moved = 0.0
    for j_idx, j in enumerate(_mlnc.PLAYS):
        r = _basis.THRESHOLDS[j]
        up = s < g[0]  # relaxed at the first sample, as the play is
        total = np.empty(len(g))
        for i, gi in enumerate(g):
            up = np.where(gi >= s + r, True, np.where(gi <= s - r, False, up))
            total[i] = np.sum(np.where(up, f, -f)) * ds
        terms = cols[:, [k * n + j_idx for k in range(len(coef))]] @ coef
        expect = 2 * (H[:, j] + terms) - G(S) - G(-S)
        # The grid places each switching boundary within one relay cell.
        np.testing.assert_allclose(total, expect, atol=2 * np.abs(f).max() * ds)
        moved = max(moved, float(np.ptp(terms)))
    assert moved > 0.05  # the centre dependence shows: the check is not vacuous


def test_eight_bands_are_tried_where_the_search_has_forty_samples_per_coefficient():
    from piest_jax._diagnosis.effects import minor_loop_noncongruence as _mlnc

    e = EFFECT["minor_loop_noncongruence"]
    need = _mlnc.SAMPLES_PER_TERM * e.n_play_terms("eight_bands")
    assert e.n_play_terms("eight_bands") == 7 * len(_mlnc.PLAYS)
    assert "eight_bands" not in e.grid(_record(n=need - 1))
    assert e.grid(_record(n=need)) == list(_mlnc.FORMS)
    # The coarse forms are charged alike, so held-out error alone chooses among them; the eight
    # bands pay for their own coefficients.
    assert {e.charge(f) for f in ("linear", "two_bands", "four_bands")} == {e.n_play_terms("four_bands")}
    assert e.charge("eight_bands") == e.n_play_terms("eight_bands")


def test_reversal_spread_sees_loops_at_several_heights():
    from piest_jax._diagnosis.scaling import reversal_spread

    t = np.linspace(0, 10, 4001)
    steady = np.sin(2 * np.pi * t)
    assert reversal_spread(steady) < 1e-6
    # Cycle k has amplitude A_k: its maximum sits at (1 + A_k) / 2 of the range, its minimum at
    # (1 - A_k) / 2 (the range is [-1, 1], set by the largest cycle).
    amps = np.linspace(0.4, 1.0, 10)
    stepped = amps[np.minimum(t.astype(int), 9)] * np.sin(2 * np.pi * t)
    expect = 0.5 * (np.percentile(amps, 90) - np.percentile(amps, 10))
    assert abs(reversal_spread(stepped) - expect) < 1e-3
    # One different loop (a start from rest, here a first cycle at half amplitude) hardly counts.
    first = np.where(t < 1, 0.5, 1.0) * steady
    assert reversal_spread(first) < 0.1 <= reversal_spread(stepped)


def test_a_record_of_one_repeated_loop_does_not_try_noncongruence():
    # A steady sine traces one loop: play terms could only reshape it, as a function of the
    # output does, and would say nothing of loops elsewhere. The search leaves the effect out
    # and says why.
    from piest_jax._data.record import Record
    from piest_jax._diagnosis import diagnose as _diagnose

    t = np.arange(1500) * 1e-3
    u = np.sin(2 * np.pi * 4 * t)
    H = _basis.plays(u, _basis.THRESHOLDS, np.zeros((1, _basis.N_PLAYS)))[0]
    y = H @ np.linspace(1.0, 0.2, _basis.N_PLAYS) + 0.3 * H[:, 8] ** 2
    y = y + np.random.default_rng(0).normal(0, 1e-3, len(t))
    s = _diagnose.search(
        Record(t, u, y), candidates=("asymmetry", "minor_loop_noncongruence"), solver=None, uncertainty=False
    )
    assert "minor_loop_noncongruence" in s["rounds"][0]["untried"]
    assert all("minor_loop_noncongruence" not in r["candidates"] for r in s["rounds"])
    assert "asymmetry" in s["rounds"][0]["candidates"]


def _stepped_loops(t):
    """Cycles of 1 Hz whose amplitude steps from 0.4 to 1 over ten seconds: loops at ten heights."""
    amps = np.linspace(0.4, 1.0, 10)
    return amps[np.minimum(t.astype(int), 9)] * np.sin(2 * np.pi * t)


def test_one_repeated_loop_leaves_the_input_envelopes_out():
    # One loop traced again shows its shape, which the output map gives it as well; an input
    # envelope would add a claim about loops elsewhere (how their widths change with where they
    # sit) that the record cannot check. Loops at several heights can.
    t = np.linspace(0, 10, 4001)
    steady = Prepared(np.sin(2 * np.pi * t), np.zeros(t.size), t, rate_scale=5.0, period=1.0)
    varied = Prepared(_stepped_loops(t), np.zeros(t.size), t, rate_scale=5.0, period=1.0)
    asym, sat = EFFECT["asymmetry"], EFFECT["saturation"]
    assert asym.grid(steady) == [None] and asym.neighbours(None, 0) == []
    assert sat.grid(steady) == [_saturation.NONE] and sat.neighbours(_saturation.NONE, 0) == []
    g = np.linspace(-1, 1, 9)
    assert asym.input_map(None, g) is g and not asym.changes_plays(None) and not asym.static(None)
    assert {0.2, -0.2} <= set(asym.grid(varied)) and len(sat.grid(varied)) > 1


def _creep_record(drive):
    """PI output plus creep of one drive, on loops at several heights with two holds."""
    dt, t = 0.01, np.arange(3000) * 0.01
    u = 0.8 * _stepped_loops(t / 3)
    for a in (900, 2100):
        u[a : a + 300] = u[a]
        u[a + 300 :] += u[a] - u[a + 300]
    H = _basis.plays(u, _basis.THRESHOLDS, np.zeros((1, _basis.N_PLAYS)))[0]
    v = H @ np.linspace(0.6, 0.05, _basis.N_PLAYS)
    d = u if drive == "input" else v
    lag = np.asarray(_creep.lowpass(d, np.exp(-dt / np.array([0.7, 4.0])))).sum(axis=1) - 2 * d
    y = v + 0.3 * lag + np.random.default_rng(1).normal(0, 1e-3, t.size)
    folds = np.minimum(np.arange(t.size) * N_BLOCKS // t.size, N_BLOCKS - 1)
    return Prepared(u, y, t, rate_scale=5.0, period=3.0, folds=np.where(folds == 0, -1, folds % N_FOLDS))


@pytest.mark.parametrize("drive", ["input", "output"])
def test_creep_is_found_with_the_drive_that_made_it(drive):
    # Lags of the input (`piest fit`'s creep operator) and lags of the output (a yield of the
    # displacement itself) creep differently after a reversal, where the plays hold the output
    # while the input moves: the search's held-out blocks tell them apart.
    from piest_jax._diagnosis import diagnose as _diagnose

    p = _creep_record(drive)
    grid = EFFECT["creep"].grid(p)
    assert {q.drive for q in grid} == {"input", "output"}
    mse, q = _diagnose._fit_many(p, {}, "creep", grid)
    assert q.drive == drive
    # The other drive's best fit predicts the held-out blocks worse.
    other = [g for g in grid if g.drive != drive]
    assert _diagnose._fit_many(p, {}, "creep", other)[0] > 1.5 * mse


@pytest.mark.parametrize("name", ["asymmetry", "saturation"])
def test_output_map_slopes_are_the_derivatives_of_its_terms(name):
    # The Gauss-Newton steps of `model.fit` rest on them; central differences are the reference.
    e = EFFECT[name]
    norm = (0.3, 1.7)
    v = np.linspace(-2.0, 2.6, 301)  # beyond the powers' held range on both sides
    h = 1e-6
    fd = (e.terms(v + h, norm) - e.terms(v - h, norm)) / (2 * h)
    raw = np.abs((v - norm[0]) / norm[1])
    away = np.abs(raw - _output_map.POLY_RANGE) > 1e-3  # the held range's kink has no derivative
    np.testing.assert_allclose(e.term_slopes(v, norm)[away], fd[away], rtol=1e-6, atol=1e-8)
    assert e.terms(v, norm).shape == e.term_slopes(v, norm).shape == (len(v), e.n_terms)
