"""The Monte Carlo PE map: per-draw statistics against NumPy loops, the sharper condition on
constructed cases, reproducibility, chunking and sharding invariance, and the CLI."""

import json
import os
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from reference import play as ref_play

import piest_jax as pj
from piest_jax._cli import main
from piest_jax._excitation import montecarlo as M
from piest_jax._excitation.draw import draw_case
from piest_jax._excitation.families import FAMILIES
from piest_jax._excitation.signals import triangle

pytestmark = pytest.mark.long

SETTINGS = dict(n_samples=600, n_plays=4, window=150, stride=15, dt=0.01)
N_DRAWS, CHUNK, SEED = 168, 84, 11


@pytest.fixture(scope="module")
def settings():
    return pj.make_settings(**SETTINGS, dtype="float64")


@pytest.fixture(scope="module")
def pemap(settings):
    return pj.pe_map(jax.random.key(SEED), N_DRAWS, settings, chunk=CHUNK, quiet=True)


def _reference(u, r, x0, w, s):
    """Every per-draw statistic by plain loops over windows, in float64."""
    H = ref_play(u, r, x0)
    n = len(r)
    lo, hi, ranges, excited, holds = [], [], [], [], []
    for st in range(0, s.n_samples - s.window + 1, s.stride):
        Hw, uw = H[st : st + s.window], u[st : st + s.window]
        ev = np.linalg.eigvalsh(Hw.T @ Hw / s.window)
        lo.append(ev[0])
        hi.append(ev[-1])
        ranges.append(np.ptp(uw))
        moving = np.ptp(Hw, axis=0) > 0
        excited.append(moving)
        # distinct shapes: moving plays whose difference is not constant over the window
        reps = []
        for i in np.flatnonzero(moving):
            if not any(np.ptp(Hw[:, i] - Hw[:, j]) <= 1e-9 for j in reps):
                reps.append(i)
        steps = np.sum(np.any(np.diff(Hw, axis=0) != 0, axis=1))
        zero = np.any(~moving & (np.abs(Hw[0]) <= 1e-12))
        twin = [[np.ptp(np.abs(Hw[:, i] - Hw[:, j])) <= 1e-12 for j in range(n)] for i in range(n)]
        triple = any(
            twin[i][j] and twin[i][k] and twin[j][k] for i in range(n) for j in range(i + 1, n) for k in range(j + 1, n)
        )
        holds.append(n <= min(len(reps), steps) + 1 and not zero and not triple)
    est = pj.ContinuousRLS(s.P0, s.dt)
    W = np.asarray(pj.estimate(est, H[: s.rls_samples], H[: s.rls_samples] @ w).weights)
    Wk = W[-1]
    lo, hi = np.array(lo), np.array(hi)
    return _convergence_reference(H, u, r, w, W, s) | dict(
        rho=min(ranges) / (2 * r[-1]),
        c1=lo.min(),
        c1_normalised=np.min(lo / hi),
        excited=np.array(excited),
        min_excited=np.array(excited).sum(axis=1).min(),
        sharper=all(holds),
        weight_error=np.linalg.norm(np.asarray(Wk) - w) / np.linalg.norm(w),
        scale=hi.max(),
    )


def _first_for_good(values, checks):
    below = np.asarray(values) <= 0.01
    later = [i for i in range(len(checks)) if below[i:].all()]
    return checks[later[0]] if later else -1


def _convergence_reference(H, u, r, w, W, s):
    """Times to 1 % weight error, measured by the paper's RLS and bounded by the margins."""
    checks = [min(k, s.rls_samples) for k in range(s.stride, s.rls_samples + s.stride, s.stride)]
    # W[k] is the estimate after sample k, i.e. after k + 1 samples
    err = [np.linalg.norm(W[k - 1] - w) / np.linalg.norm(w) for k in checks]
    A = np.zeros((len(r), len(r)))
    worst, k0 = [], 0
    for k in checks:
        for i in range(k0, k):
            A += s.dt / (1 + H[i] @ H[i]) ** 2 * np.outer(H[i], H[i])
        k0 = k
        worst.append(1 / (1 + s.P0 * max(np.linalg.eigvalsh(A)[0], 0.0)))
    # the bound, from pe_margin on disjoint windows
    margins = np.asarray(pj.pe_margin(H, u, r, s.window, stride=s.stride))
    step = -(-s.window // s.stride)
    total, guaranteed = 1.0, -1
    for j, a in enumerate(range(0, s.rls_samples - s.window + 1, step * s.stride)):
        peak = max(H[i] @ H[i] for i in range(a, a + s.window))
        total += s.P0 * s.window * s.dt / (1 + peak) ** 2 * margins[j * step]
        if guaranteed < 0 and total >= 100:
            guaranteed = min(-(-(a + s.window) // s.stride) * s.stride, s.rls_samples)
    return dict(
        samples_to_1pct=_first_for_good(err, checks),
        worst_samples_to_1pct=_first_for_good(worst, checks),
        worst_error=worst[-1],
        guaranteed_samples_to_1pct=guaranteed,
        guaranteed_error=1 / total,
    )


def _case(settings, i):
    key = pj.draw_keys(jax.random.key(SEED), i, 1)[0]
    t = settings.times()
    family = int(pj.draw_family(i, settings))
    draw = jax.jit(draw_case, static_argnums=(1, 3))
    return [np.asarray(a) for a in draw(key, family, t, settings.n_plays)]


@pytest.mark.parametrize("i", [0, 16, 25, 34])  # sine, noise, triangle, steps
def test_draws_match_numpy_reference(pemap, settings, i):
    assert FAMILIES[pemap.family[i]] == FAMILIES[i % 7]
    u, r, x0, w = _case(settings, i)
    # drawn here op by op, in the engine fused: the same numbers up to rounding
    np.testing.assert_allclose(pemap.thresholds[i], r, rtol=1e-13)
    ref = _reference(u, r, x0, w, settings)
    np.testing.assert_allclose(pemap.rho[i], ref["rho"], rtol=1e-12)
    np.testing.assert_allclose(pemap.c1[i], ref["c1"], atol=1e-10 * ref["scale"])
    np.testing.assert_allclose(pemap.c1_normalised[i], ref["c1_normalised"], atol=1e-10)
    np.testing.assert_allclose(pemap.gram_scale[i], ref["scale"], rtol=1e-12)
    np.testing.assert_array_equal(pemap.excited[i], ref["excited"])
    assert pemap.min_excited[i] == ref["min_excited"]
    assert pemap.sharper[i] == ref["sharper"]
    np.testing.assert_allclose(pemap.weight_error[i], ref["weight_error"], rtol=1e-5, atol=1e-9)
    for k in ("samples_to_1pct", "worst_samples_to_1pct", "guaranteed_samples_to_1pct"):
        assert getattr(pemap, k)[i] == ref[k], k
    np.testing.assert_allclose(pemap.worst_error[i], ref["worst_error"], rtol=1e-8)
    np.testing.assert_allclose(pemap.guaranteed_error[i], ref["guaranteed_error"], rtol=1e-8)


def test_map_counts(pemap, settings):
    s = pj.summarise(pemap)
    assert s["n"] == N_DRAWS
    # the map covers both sides of Assumption 1 and both outcomes
    assert 0 < s["assumption_holds"] < N_DRAWS and 0 < s["pe"] < N_DRAWS
    # the sharper_* keys count the exact condition: on this map it agrees with the verdict
    assert s["sharper_fails_pe"] == 0 and s["sharper_holds_not_pe"] == 0
    assert s["exact_condition"]["violations"] == 0
    # the earlier condition is necessary: no draw fails it and is still PE
    assert s["old_sharper_fails_pe"] == 0
    # every counterexample to Theorem 1 on this map is one the exact condition explains
    assert s["theorem_violations_failing_sharper"] == s["theorem_violations"]
    assert sum(f["n"] for f in s["per_family"].values()) == N_DRAWS
    # the margin is a lower bound on c1 for every draw, positive exactly where the condition holds
    assert s["margin"]["violations"] == 0
    assert np.all((pemap.margin > 0) == pemap.exact)
    assert np.all(pemap.margin <= pemap.c1 + s["tolerance"] * pemap.gram_scale)
    # measured error <= its worst case over weights <= the margins' guarantee, and the times too
    conv = s["convergence"]
    assert conv["violations"] == 0
    assert 0 < conv["guaranteed_1pct"] <= conv["worst_case_reached_1pct"] <= conv["reached_1pct"]
    g, w = pemap.guaranteed_samples_to_1pct, pemap.worst_samples_to_1pct
    assert np.all(w[g > 0] <= g[g > 0]) and np.all(w[g > 0] > 0)


CASE = dict(n_samples=2001, n_plays=3, window=300, stride=10, dt=2e-3)
T_CASE = np.arange(2001) * 2e-3


def _stats(u, r, x0, w=None):
    s = pj.make_settings(**CASE, dtype="float64")
    w = np.ones(len(r)) if w is None else w
    out = jax.jit(pj.draw_statistics, static_argnums=4)(
        jnp.asarray(u), jnp.asarray(r, float), jnp.asarray(x0, float), jnp.asarray(w, float), s
    )
    return {k: np.asarray(v) for k, v in out.items()}, pj.numerical_tolerance("float64")


def test_paper_setting_is_pe():
    st, tol = _stats(10 * np.sin(2 * np.pi * 5 * T_CASE), [0, 10 / 3, 20 / 3], [0, 0, 0])
    assert st["rho"] >= 1 and st["c1_normalised"] > tol and st["sharper"]
    assert st["weight_error"] < 1e-3


def test_theorem1_holds_where_its_proof_applies():
    # Theorem 1's proof needs, in every window, a reversal followed by travel of 2 r_max. Sines
    # with a whole period in each window give exactly that whenever rho >= 1: a few hundred random
    # draws (amplitudes on both sides of Assumption 1, r_1 = 0, relaxed or random initial
    # states) must show no violation.
    s = pj.make_settings(**CASE, dtype="float64")
    rng = np.random.default_rng(5)
    n_draws, n = 300, 3
    r = np.sort(rng.uniform(0.05, 1.0, (n_draws, n)), axis=1)
    r[:, 0] = 0.0
    r_max = r[:, -1]
    amp = r_max * np.exp(rng.uniform(np.log(0.5), np.log(3.0), n_draws))
    freq = rng.uniform(1.05, 4.0, n_draws) / (CASE["window"] * CASE["dt"])  # > 1 period per window
    phase = rng.uniform(0, 2 * np.pi, n_draws)
    u = amp[:, None] * np.sin(2 * np.pi * freq[:, None] * T_CASE[None, :] + phase[:, None])
    relaxed = rng.uniform(size=n_draws) < 0.5
    x0 = np.where(relaxed[:, None], 0.0, u[:, :1] + r * rng.uniform(-1, 1, (n_draws, n)))
    stats = jax.jit(jax.vmap(pj.draw_statistics, in_axes=(0, 0, 0, None, None)), static_argnums=4)(
        jnp.asarray(u), jnp.asarray(r), jnp.asarray(x0), jnp.ones(n), s
    )
    rho, c1 = np.asarray(stats["rho"]), np.asarray(stats["c1_normalised"])
    holds, tol = rho >= 1, pj.numerical_tolerance("float64")
    assert 100 < holds.sum() < n_draws  # both sides of the assumption are covered
    assert np.all(c1[holds] > tol), rho[holds & (c1 <= tol)]


def test_theorem1_counterexample():
    # A triangle of amplitude 4 r_max: windows at a turn have range 2.4 r_max (rho = 1.2), but a
    # window inside a rising leg, once every play rides its envelope, has H_j = u - r_j for all j:
    # three plays in span{1, u}. Assumption 1 holds; the plays are not PE.
    st, tol = _stats(np.asarray(triangle(T_CASE, 4.0, 0.5)), [0.25, 0.5, 1.0], [0, 0, 0])
    assert st["rho"] >= 1.1
    assert st["c1_normalised"] <= tol
    assert not st["sharper"]


def test_frozen_plays():
    u = 0.3 * np.sin(2 * np.pi * T_CASE)
    # two plays frozen (|u - x0| <= r all along): linearly dependent, detected
    st, tol = _stats(u, [0.0, 0.5, 1.0], [0.0, 0.1, -0.4])
    assert st["rho"] < 1 and st["c1_normalised"] <= tol and not st["sharper"]
    assert st["min_excited"] == 1 and not st["excited"][:, 1:].any()
    # one play frozen at a non-zero value, the others moving differently: PE below Assumption 1
    st, tol = _stats(u, [0.0, 0.1, 0.5], [0.0, 0.0, 0.1])
    assert st["rho"] < 1 and st["c1_normalised"] > tol and st["sharper"]
    # the same play frozen at zero is a zero column: not PE
    st, tol = _stats(u, [0.0, 0.1, 0.5], [0.0, 0.0, 0.0])
    assert st["c1_normalised"] <= tol and not st["sharper"] and st["zero_frozen"]


def test_unresolved_thresholds():
    # Thresholds 1e-5 apart while u moves about 0.05 per sample where the plays leave an
    # envelope: they leave it at the same sample, so h_j - h_i only flips sign: three twins,
    # singular windows, although the three shapes differ and every play moves.
    u = 3.0 * np.sin(2 * np.pi * 2.0 * T_CASE)
    st, tol = _stats(u, [0.5, 0.50001, 0.50002], [0, 0, 0])
    assert st["rho"] >= 1 and st["min_excited"] == 3 and st["redundant"] <= 1
    assert st["c1_normalised"] <= tol and st["twin_triple"] and not st["sharper"]
    st, tol = _stats(u, [0.5, 0.6, 0.7], [0, 0, 0])
    assert st["c1_normalised"] > tol and not st["twin_triple"] and st["sharper"]


def test_sharper_condition_public():
    u = triangle(jnp.asarray(T_CASE), 4.0, 0.5)
    H = pj.play(u, jnp.array([0.25, 0.5, 1.0]))
    holds = jax.jit(pj.sharper_condition, static_argnums=2, static_argnames="stride")(H, u, 300, stride=10)
    assert holds.shape == (171,) and holds.any() and not holds.all()
    with pytest.raises(ValueError, match="must be between 1 and the signal length"):
        pj.sharper_condition(H, u, 3000)
    with pytest.raises(ValueError, match=r"`H` must be \(T, n\)"):
        pj.sharper_condition(H[:, 0], u, 30)


def test_same_seed_same_map_other_seed_differs(pemap, settings):
    again = pj.pe_map(jax.random.key(SEED), N_DRAWS, settings, chunk=CHUNK, quiet=True)
    for k in ("rho", "c1", "excited", "weight_error", "family"):
        np.testing.assert_array_equal(getattr(again, k), getattr(pemap, k))
    other = pj.pe_map(jax.random.key(SEED + 1), CHUNK, settings, chunk=CHUNK, quiet=True)
    same = np.all(other.thresholds == pemap.thresholds[:CHUNK], axis=1)
    assert not same.any()


def _assert_same_map(a, b):
    """Discrete results equal; floats equal up to the summation order a batch size may choose."""
    for k in ("family", "excited", "min_excited", "redundant", "sharper", "thresholds"):
        np.testing.assert_array_equal(a[k], b[k])
    for k in ("rho", "c1_normalised", "gram_scale"):
        np.testing.assert_allclose(a[k], b[k], rtol=1e-12, atol=1e-15)
    # an eigenvalue is known to a few eps of the matrix's norm, whatever its own size
    eps = np.finfo(np.float64).eps
    assert np.all(np.abs(a["c1"] - b["c1"]) <= 1e-12 * np.abs(b["c1"]) + 16 * eps * b["gram_scale"])
    # (I + P0 A)⁻¹ W amplifies the rounding of A by up to P0 λmax(A)
    np.testing.assert_allclose(a["weight_error"], b["weight_error"], rtol=1e-8)


def test_chunking_invariance(pemap, settings):
    # draws 42..132 as a chunk of 84 and a padded one of 7 (the same compiled program); the
    # fixture's chunks split them at 84
    part = pj.pe_map(jax.random.key(SEED), 91, settings, chunk=CHUNK, start=42, quiet=True)
    assert part.rho.shape == (91,)
    _assert_same_map(part.arrays(), {k: v[42:133] for k, v in pemap.arrays().items()})
    with pytest.raises(ValueError, match="`start` must be a non-negative multiple of 7"):
        pj.pe_map(jax.random.key(SEED), 50, settings, start=5)


def _cpu_map(pemap, settings):
    """The fixture's map as one CPU device computes it (the subprocesses below run on CPUs).

    On an accelerator the in-process map runs there, whose eigensolver rounds otherwise.
    """
    if jax.default_backend() == "cpu":
        return pemap
    return pj.pe_map(jax.random.key(SEED), N_DRAWS, settings, chunk=CHUNK, devices=jax.devices("cpu")[:1], quiet=True)


def test_sharded_equals_single_device(pemap, settings, tmp_path):
    script = textwrap.dedent(
        f"""
        import jax, numpy as np
        jax.config.update("jax_enable_x64", True)
        import piest_jax as pj
        from piest_jax._excitation import montecarlo as M
        assert len(jax.devices()) == 4, jax.devices()
        s = pj.make_settings(**{SETTINGS!r}, dtype="float64")
        fn, sharding = M._engine(s, tuple(jax.devices()))
        assert sharding == pj.mesh_sharding(jax.devices())
        assert sharding.mesh.shape == {{"batch": 4}}
        out = fn(jax.device_put(pj.draw_keys(jax.random.key({SEED}), 0, 56), sharding))
        assert len(out["rho"].sharding.device_set) == 4
        res = pj.pe_map(jax.random.key({SEED}), {N_DRAWS}, s, chunk=56, quiet=True)
        np.savez(r"{tmp_path / "sharded.npz"}", **res.arrays())
        """
    )
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=4")
    env["JAX_PLATFORMS"] = "cpu"
    proc = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-2000:]
    sharded = np.load(tmp_path / "sharded.npz")
    _assert_same_map(sharded, _cpu_map(pemap, settings).arrays())


def test_many_windows_on_two_devices_finish(tmp_path):
    # 571 windows of 10 plays per draw: one batched eigensolver call per draw splits into pool
    # tasks and, on two devices sharing a two-thread pool, waited forever; it must finish.
    script = textwrap.dedent(
        f"""
        import jax, numpy as np
        jax.config.update("jax_enable_x64", True)
        import piest_jax as pj
        assert len(jax.devices()) == 2, jax.devices()
        s = pj.make_settings(n_samples=600, n_plays=10, window=30, stride=1, dt=0.01)
        res = pj.pe_map(jax.random.key(3), 28, s, chunk=28, quiet=True)
        np.savez(r"{tmp_path / "two.npz"}", **res.arrays())
        """
    )
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=2")
    env["JAX_PLATFORMS"] = "cpu"
    try:
        proc = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=300)
    except subprocess.TimeoutExpired:
        pytest.fail("the two-device map did not finish in 300 s (eigensolver deadlock?)")
    assert proc.returncode == 0, proc.stderr[-2000:]
    s = pj.make_settings(n_samples=600, n_plays=10, window=30, stride=1, dt=0.01, dtype="float64")
    one = pj.pe_map(jax.random.key(3), 28, s, chunk=28, devices=jax.devices("cpu")[:1], quiet=True)
    two = np.load(tmp_path / "two.npz")
    # (which plays count as moving is a tolerance decision on sums that another compilation may
    # round differently; the map's own values must agree)
    np.testing.assert_array_equal(two["thresholds"], one.thresholds)
    for k in ("rho", "c1_normalised", "gram_scale"):
        np.testing.assert_allclose(two[k], getattr(one, k), rtol=1e-12, atol=1e-15)
    tol = pj.numerical_tolerance("float64")
    np.testing.assert_array_equal(two["c1_normalised"] > tol, one.c1_normalised > tol)


def test_batch_as_one_vmap_equals_the_loop(pemap, settings):
    # the layout an accelerator gets: the same statistics as the CPU's draw-by-draw loop
    keys = pj.draw_keys(jax.random.key(SEED), 0, 14)
    out = jax.jit(lambda k: M._local_batch(k, settings, loop=False))(keys)
    _assert_same_map(
        {k: np.asarray(v) for k, v in out.items()} | {"family": pemap.family[:14]},
        {k: v[:14] for k, v in pemap.arrays().items()},
    )


def test_settings_errors():
    with pytest.raises(ValueError, match="`n_samples` must be a whole number >= 2"):
        pj.make_settings(n_samples=0)
    with pytest.raises(ValueError, match=r"`window` \(700\) is longer than the signal \(600"):
        pj.make_settings(n_samples=600, window=700)
    with pytest.raises(ValueError, match="`stride` must be a whole number >= 1"):
        pj.make_settings(n_samples=600, stride=0)
    with pytest.raises(ValueError, match="`P0` must be a positive finite number"):
        pj.make_settings(n_samples=600, P0=-1.0)
    with pytest.raises(ValueError, match="unknown input family 'square'"):
        pj.make_settings(n_samples=600, families=["sine", "square"])
    s = pj.make_settings(n_samples=600)
    with pytest.raises(ValueError, match="`n_draws` must be a positive whole number"):
        pj.pe_map(jax.random.key(0), 0, s)


def test_cli_writes_map(tmp_path, pemap, settings, capsys):
    out = tmp_path / "map"
    args = ["montecarlo", "--inputs", str(CHUNK), "--samples", "600", "--seed", str(SEED)]
    args += ["--plays", "4", "--window", "150", "--stride", "15", "--dt", "0.01"]
    assert main(args + ["--out", str(out), "--quiet"]) == 0
    printed = capsys.readouterr().out.split()
    assert printed == [str(out / "pe_map.png"), str(out / "pe_map.json")]
    assert (out / "pe_map.png").stat().st_size > 10_000
    rep = json.loads((out / "pe_map.json").read_text())
    for k in ("n_inputs", "theorem_violations", "pe_fraction_below_assumption", "seconds"):
        assert k in rep
    assert rep["n_inputs"] == CHUNK and rep["tolerance"] == pj.numerical_tolerance("float64")
    np.testing.assert_array_equal(rep["draws"]["rho"], pemap.rho[:CHUNK])
    pe = pemap.c1_normalised[:CHUNK] > rep["tolerance"]
    assert rep["theorem_violations"] == int(np.sum((pemap.rho[:CHUNK] >= 1) & ~pe))
    # The command writes what the library call returns (less the timings), plus the seed.
    lib = pj.pe_map(jax.random.key(SEED), CHUNK, settings, quiet=True)
    want = json.loads(pj.write_json(tmp_path / "lib.json", lib.to_json()).read_text())
    assert rep.pop("seed") == SEED
    for r in (rep, want):
        r.pop("seconds"), r["settling"].pop("seconds")
    assert rep == want
    # refuses to overwrite without --force
    assert main(args + ["--out", str(out), "--quiet"]) == 2


@pytest.mark.parametrize(
    "bad, message",
    [
        (["--inputs", "0"], "must be positive"),
        (["--samples", "-5"], "must be positive"),
        (["--samples", "100", "--window", "200"], "longer than the signal"),
        (["--families", "sine,square"], "unknown --families"),
    ],
)
def test_cli_rejects_bad_arguments(tmp_path, capsys, bad, message):
    with pytest.raises(SystemExit) as exc:
        code = main(["montecarlo", "--out", str(tmp_path / "x"), *bad])
        raise SystemExit(code)
    assert exc.value.code == 2
    assert message in capsys.readouterr().err
