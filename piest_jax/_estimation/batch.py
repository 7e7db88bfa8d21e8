"""Batch estimation experiments: one jitted `vmap` over many settings.

Each batch member has its own input, true weights (constant, or changing over time), estimator
(`"continuous"`, `"forgetting"` or `"gradient"`), P0, forgetting factor, gradient gain and
measurement-noise level; the thresholds, dt and the static options are shared. Every member is
simulated (y_k = h_kᵀW_k + σ ε_k) and estimated inside one compiled `vmap`. When a batch mixes
estimators, `lax.switch` picks each member's; under `vmap` that evaluates every estimator present
in the batch, so batches of one estimator cost only that one.

The noise for member i is `noise_std[i] * jax.random.normal(jax.random.split(key, B)[i], (T,))`,
so any member can be rerun on its own.

[`noise_study`][] uses it for the two questions measurement noise raises: the bias and spread of
the final estimate against the noise level (checked against the closed-form covariance), and the
forgetting-factor trade-off (a shorter memory re-converges faster after the weights change, but
averages the noise over fewer samples); [`noise_figure`][] draws both.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jaxtyping import Array, ArrayLike, Bool, Float, Int, PRNGKeyArray

from .. import _checks
from .._operators.play import play
from .certificate import noise_covariance
from .estimators import AbstractEstimator
from .gradient import NormalisedGradient
from .rls import NORMALISATIONS, WINDUPS, ContinuousRLS, ForgettingRLS

ESTIMATORS = ("continuous", "forgetting", "gradient")


class BatchStats(eqx.Module):
    """Convergence statistics of a batch, one row per member.

    **Fields:**

    - `final_weights` (B, n): the estimate after the last sample.
    - `final_error` (B, n): final estimate minus the final true weights.
    - `settle_index` (B,): the first sample after which every weight stays within `rtol`
      (relative) of its final true value; T when the last sample is still outside.
    - `rms_prediction_error` (B,): RMS of the a-priori prediction error over the second half.
    - `finite` (B,): whether the whole estimate trajectory stayed finite.
    """

    final_weights: Float[Array, "batch n"]
    final_error: Float[Array, "batch n"]
    settle_index: Int[Array, " batch"]
    rms_prediction_error: Float[Array, " batch"]
    finite: Bool[Array, " batch"]


def trajectory(estimator: AbstractEstimator, H, y, initial_weights) -> tuple[Array, Array]:
    """The estimate (T, n) and a-priori prediction error (T,) of one run, nothing else.

    A lighter scan than `estimate` (no gain-matrix statistics), for use inside big batches; the
    data are not validated here.
    """

    def body(state, hy):
        state = estimator.step(state, *hy)
        return state, (estimator.weights(state), estimator.prediction_error(state))

    _, (w, e) = lax.scan(body, estimator.init(initial_weights), (H, y))
    return w, e


def settle_index(weights, truth, rtol) -> Int[Array, ""]:
    """First index after which every weight stays within `rtol` of `truth`; T if never."""
    ok = jnp.all(jnp.abs(weights - truth) <= rtol * jnp.abs(truth), axis=1)
    idx = jnp.arange(ok.shape[0])
    last_bad = jnp.max(jnp.where(ok, -1, idx))
    return jnp.where(ok[-1], last_bad + 1, ok.shape[0])


def _estimator_indices(estimator, B: int) -> tuple[tuple[str, ...], Array]:
    names = [estimator] * B if isinstance(estimator, str) else list(estimator)
    if len(names) != B:
        raise ValueError(f"`estimator` has {len(names)} entries but the batch has {B} members")
    for name in names:
        if name not in ESTIMATORS:
            raise ValueError(f"unknown estimator {name!r}; choose from {ESTIMATORS}")
    used = tuple(e for e in ESTIMATORS if e in names)
    return used, jnp.asarray([used.index(e) for e in names], jnp.int32)


def _per_member(x, B: int, name: str, dtype) -> Array:
    x = jnp.asarray(x, dtype)
    if x.ndim > 1 or (x.ndim == 1 and x.shape[0] != B):
        raise ValueError(f"`{name}` must be a scalar or have one entry per member ({B}), got {x.shape}")
    return jnp.broadcast_to(x, (B,))


def run_batch(
    inputs: Float[ArrayLike, "batch time"],
    true_weights: Float[ArrayLike, "batch n"] | Float[ArrayLike, "batch time n"],
    thresholds,
    *,
    key: PRNGKeyArray,
    estimator="continuous",
    P0=None,
    noise_std=0.0,
    forgetting=None,
    gain=None,
    dt: float = 1e-3,
    normalisation: str = "paper",
    windup: str = "trace",
    rtol: float = 0.01,
) -> BatchStats:
    """Simulate and estimate every member of a batch in one compiled `vmap`.

    **Arguments:**

    - `inputs`: (B, T) input signals.
    - `true_weights`: (B, n), or (B, T, n) for weights that change over time (then
      y_k = h_kᵀW_k and the statistics refer to the final weights W_T).
    - `thresholds`: (n,), increasing, shared by the batch.
    - `key`: PRNG key for the measurement noise (split once per member, see the module docs).
    - `estimator`: one name from `ESTIMATORS` or one per member; or an estimator object (any
      [`AbstractEstimator`][], yours included) shared by every member, or one object per member,
      all of one class with the same static settings (their array settings, such as P0, are
      stacked and batched).
    - `P0`: initial gain P0·I of named least-squares estimators, scalar or (B,) (default 1e8).
    - `noise_std`: standard deviation of white Gaussian noise on y, scalar or (B,).
    - `forgetting`: λ of `"forgetting"` members, scalar or (B,) (default 1).
    - `gain`: μ of `"gradient"` members, scalar or (B,) (default 1).
    - `dt`, `normalisation`: of `"continuous"` members; `windup`: of `"forgetting"` members.
      An estimator object carries its own settings: `P0`, `forgetting` and `gain` are then
      refused, and `dt`, `normalisation`, `windup` are not used.
    - `rtol`: relative tolerance for `settle_index`.

    **Returns:** a [`BatchStats`][].
    """
    key = _checks.prng_key(key)
    inputs = _checks.as_float_array(inputs, "inputs")
    if inputs.ndim != 2 or inputs.shape[1] < 1:
        raise ValueError(f"`inputs` must be (B, T), one signal per member, got {inputs.shape}")
    B, T = inputs.shape
    r = _checks.thresholds(thresholds, sorted_=True)
    if r.ndim != 1:
        raise ValueError(f"`thresholds` must be a vector (n,), got shape {r.shape}")
    n = r.shape[0]
    w = _checks.as_float_array(true_weights, "true_weights")
    if w.ndim not in (2, 3) or w.shape[0] != B or (w.ndim == 3 and w.shape[1] != T):
        raise ValueError(f"`true_weights` must be (B, n) or (B, T, n) with B = {B}, T = {T}, got {w.shape}")
    if w.shape[-1] != n:
        raise ValueError(f"{w.shape[-1]} true weights per member but {n} thresholds")
    if normalisation not in NORMALISATIONS:
        raise ValueError(f"unknown normalisation {normalisation!r}; choose one of {NORMALISATIONS}")
    if windup not in WINDUPS:
        raise ValueError(f"unknown windup protection {windup!r}; choose one of {WINDUPS}")
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"`dt` must be positive and finite, got {dt}")
    dtype = jnp.result_type(inputs, w)
    if _is_module_spec(estimator):
        given = [k for k, v in (("P0", P0), ("forgetting", forgetting), ("gain", gain)) if v is not None]
        if given:
            raise ValueError(f"`{given[0]}` is a setting of the estimator object: set it there, not in run_batch")
        est, batched = _estimator_modules(estimator, B, n)
        sigma = _per_member(noise_std, B, "noise_std", dtype)
        if _checks.is_concrete(sigma) and bool(jnp.any(sigma < 0)):
            raise ValueError("`noise_std` must be non-negative")
        inputs = _checks.finite(inputs, "inputs")
        w = _checks.finite(w.astype(dtype), "true_weights")
        return _run_modules(est, batched, rtol, inputs, w, r.astype(dtype), sigma, jax.random.split(key, B))
    used, idx = _estimator_indices(estimator, B)
    settings = {
        k: _per_member(v, B, k, dtype)
        for k, v in (
            ("P0", 1e8 if P0 is None else P0),
            ("noise_std", noise_std),
            ("forgetting", 1.0 if forgetting is None else forgetting),
            ("gain", 1.0 if gain is None else gain),
        )
    }
    if _checks.is_concrete(settings["noise_std"]) and bool(jnp.any(settings["noise_std"] < 0)):
        raise ValueError("`noise_std` must be non-negative")
    _check_settings(used, idx, settings)
    inputs = _checks.finite(inputs, "inputs")
    w = _checks.finite(w.astype(dtype), "true_weights")
    return _run(
        used,
        normalisation,
        windup,
        rtol,
        inputs,
        w,
        r.astype(dtype),
        idx,
        settings,
        jnp.asarray(dt, dtype),
        jax.random.split(key, B),
    )


def _check_settings(used, idx, s) -> None:
    """The estimators' own checks, on the members that use each estimator, before tracing."""
    if not all(_checks.is_concrete(v) for v in s.values()):
        return  # traced settings are checked by the estimators' `eqx.error_if`
    idx = np.asarray(idx)
    v = {k: np.asarray(x) for k, x in s.items()}
    for e in used:
        sel = idx == used.index(e)
        if e != "gradient" and not np.all(np.isfinite(v["P0"][sel]) & (v["P0"][sel] > 0)):
            raise ValueError(f"`P0` must be positive definite (positive) for {e!r} members")
        lam = v["forgetting"][sel]
        if e == "forgetting" and not np.all((lam > 0) & (lam <= 1)):
            raise ValueError(f"forgetting factor must be in (0, 1], got {lam.min():g}..{lam.max():g}")
        mu = v["gain"][sel]
        if e == "gradient" and not np.all((mu > 0) & (mu < 2)):
            raise ValueError(f"the normalised gradient gain must be in (0, 2), got {mu.min():g}..{mu.max():g}")


def _continuous(s, dt, normalisation, windup):
    return ContinuousRLS(s["P0"], dt, normalisation=normalisation)


def _forgetting(s, dt, normalisation, windup):
    return ForgettingRLS(s["P0"], s["forgetting"], windup=windup)


def _gradient(s, dt, normalisation, windup):
    return NormalisedGradient(s["gain"])


_MAKERS = {"continuous": _continuous, "forgetting": _forgetting, "gradient": _gradient}


@eqx.filter_jit
def _run(used, normalisation, windup, rtol, inputs, true_weights, r, idx, settings, dt, keys):
    def member(u, w, i, s, k):
        H, y, w_path = _simulate(u, w, r, s["noise_std"], k)
        w0 = jnp.zeros(r.shape[0], H.dtype)

        def branch(j):
            # Under vmap every branch runs for every member; settings that belong to another
            # estimator are replaced by harmless values so no branch trips its own checks.
            mine = i == j
            sj = {k: jnp.where(mine, v, 1.0) if k != "noise_std" else v for k, v in s.items()}
            return trajectory(_MAKERS[used[j]](sj, dt, normalisation, windup), H, y, w0)

        branches = [lambda j=j: branch(j) for j in range(len(used))]
        W, e = branches[0]() if len(branches) == 1 else lax.switch(i, branches)
        return _stats(W, e, w_path, rtol)

    return jax.vmap(member)(inputs, true_weights, idx, settings, keys)


def _simulate(u, w, r, sigma, key):
    """One member's plays H (T, n), measured output y (T,) and true weights per sample (T, n)."""
    T = u.shape[0]
    H = play(u, r)
    w_path = jnp.broadcast_to(w, (T, r.shape[0]))
    y = jnp.sum(H * w_path, axis=1) + sigma * jax.random.normal(key, (T,), H.dtype)
    return H, y, w_path


def _stats(W, e, w_path, rtol) -> BatchStats:
    final = W[-1]
    return BatchStats(
        final,
        final - w_path[-1],
        settle_index(W, w_path[-1], rtol),
        jnp.sqrt(jnp.mean(e[W.shape[0] // 2 :] ** 2)),
        jnp.all(jnp.isfinite(W)),
    )


def _is_module_spec(estimator) -> bool:
    """Whether `estimator` gives estimator objects (or classes, refused later) rather than names."""
    items = [estimator] if isinstance(estimator, AbstractEstimator | type | str) else list(estimator)
    return any(isinstance(e, AbstractEstimator) or isinstance(e, type) for e in items)


def _estimator_modules(estimator, B: int, n: int):
    """One estimator object for the batch: shared (not batched), or B objects stacked."""
    items = [estimator] if isinstance(estimator, AbstractEstimator | type) else list(estimator)
    for e in items:
        if isinstance(e, type):
            raise ValueError(
                f"`estimator` is the class {e.__name__}, not an estimator: pass an "
                f"instance with its settings, e.g. {e.__name__}(...)"
            )
        if not isinstance(e, AbstractEstimator):
            raise ValueError(f"`estimator` mixes estimator objects with {e!r}: give names or objects")
    first = items[0]
    assert isinstance(first, AbstractEstimator)  # the loop refused anything else
    if first.n_plays is not None and first.n_plays != n:
        raise ValueError(f"the estimator is set up for {first.n_plays} plays but there are {n} thresholds")
    if len(items) == 1:
        return items[0], False
    if len(items) != B:
        raise ValueError(f"`estimator` has {len(items)} entries but the batch has {B} members")
    if len({type(e) for e in items}) > 1:
        names = sorted({type(e).__name__ for e in items})
        raise ValueError(
            f"one batch runs one estimator class, got {', '.join(names)}: run one batch per class, or give names"
        )
    parts = [eqx.partition(e, eqx.is_array) for e in items]
    static = parts[0][1]
    if not all(eqx.tree_equal(static, s) for _, s in parts[1:]):
        raise ValueError(
            "the estimator objects differ in their static settings (e.g. `normalisation`): run one batch per setting"
        )
    shapes = {tuple(jnp.shape(x) for x in jax.tree.leaves(d)) for d, _ in parts}
    if len(shapes) > 1:
        raise ValueError("the estimator objects' settings differ in shape (e.g. scalar and matrix P0)")
    stacked = jax.tree.map(lambda *xs: jnp.stack(xs), *(d for d, _ in parts))
    return eqx.combine(stacked, static), True


@eqx.filter_jit
def _run_modules(est, batched, rtol, inputs, true_weights, r, sigma, keys):
    def member(est, u, w, s, k):
        H, y, w_path = _simulate(u, w, r, s, k)
        W, e = trajectory(est, H, y, jnp.zeros(r.shape[0], H.dtype))
        return _stats(W, e, w_path, rtol)

    in_axes = (eqx.if_array(0) if batched else None, 0, 0, 0, 0)
    return eqx.filter_vmap(member, in_axes=in_axes)(est, inputs, true_weights, sigma, keys)


def noise_study(
    *,
    key: PRNGKeyArray,
    replicates: int = 64,
    noise_levels=(0.01, 0.03, 0.1, 0.3, 1.0),
    forgetting=(0.9, 0.95, 0.98, 0.99, 0.995, 0.998, 1.0),
    forgetting_noise: float = 0.1,
    duration: float = 2.0,
    P0: float = 1e8,
    P0_forgetting: float = 1e3,
) -> dict:
    """Monte Carlo study of measurement noise on the Fig. 5 setting, as one `run_batch` call.

    Input u = 10 sin(2π·5t), thresholds (0, 10/3, 20/3), dt = 1 ms, `duration` seconds.

    - Noise sweep: `ContinuousRLS(P0)` with true weights (1, 3, 5) and each noise level σ,
      `replicates` noise draws each; bias and spread of the final estimate, and the spread the
      closed form predicts ([`noise_covariance`][]).
    - Forgetting sweep: `ForgettingRLS(P0_forgetting, λ)` with weights that jump from (1, 3, 5)
      to (1.5, 2.5, 5.5) half-way; for each λ the bias and spread of the final estimate under
      noise σ = `forgetting_noise`, and the noise-free time to re-converge within 1 %.

    **Arguments:** `key` (PRNG key of the noise); `replicates` noise draws per setting;
    `noise_levels` (σ of the sweep); `forgetting` (the λ values); `forgetting_noise` (σ of the
    forgetting sweep); `duration` in seconds; `P0`, `P0_forgetting` (the two estimators' P0).

    **Returns:** a JSON-ready dict (lists of numbers; inf where a run never re-converged).
    """
    if not _checks.is_whole(replicates) or replicates < 2:
        raise ValueError(f"`replicates` must be a whole number >= 2, got {replicates!r}")
    dt, r = 1e-3, np.array([0.0, 10.0 / 3.0, 20.0 / 3.0])
    t = np.arange(int(round(duration / dt)) + 1) * dt
    T, jump = len(t), len(t) // 2
    u = 10 * np.sin(2 * np.pi * 5 * t)
    w_a, w_b = np.array([1.0, 3.0, 5.0]), np.array([1.5, 2.5, 5.5])
    const = np.broadcast_to(w_a, (T, 3))
    switched = np.where((np.arange(T) < jump)[:, None], w_a, w_b)
    sig = np.asarray(noise_levels, float)
    lam = np.asarray(forgetting, float)
    n_a, n_b = len(sig) * replicates, len(lam) * (replicates + 1)
    # forgetting members: per λ, one noise-free run first, then the noisy replicates
    sig_b = np.tile(np.r_[0.0, np.full(replicates, forgetting_noise)], len(lam))
    stats = run_batch(
        np.broadcast_to(u, (n_a + n_b, T)),
        np.concatenate([np.broadcast_to(const, (n_a, T, 3)), np.broadcast_to(switched, (n_b, T, 3))]),
        r,
        key=key,
        estimator=["continuous"] * n_a + ["forgetting"] * n_b,
        P0=np.r_[np.full(n_a, P0), np.full(n_b, P0_forgetting)],
        noise_std=np.r_[np.repeat(sig, replicates), sig_b],
        forgetting=np.r_[np.ones(n_a), np.repeat(lam, replicates + 1)],
        dt=dt,
    )
    err = np.asarray(stats.final_error)
    finite = bool(np.all(np.asarray(stats.finite)))
    ea = err[:n_a].reshape(len(sig), replicates, 3)
    H = play(jnp.asarray(u), jnp.asarray(r))
    unit_cov = np.asarray(noise_covariance(H, P0, dt, 1.0))
    eb = err[n_a:].reshape(len(lam), replicates + 1, 3)
    idx = np.asarray(stats.settle_index[n_a:]).reshape(len(lam), replicates + 1)[:, 0]
    track = np.where(idx < T, (idx - jump) * dt, np.inf)
    return {
        "setting": "u = 10 sin(2 pi 5 t), r = (0, 10/3, 20/3), dt = 1 ms",
        "duration": duration,
        "replicates": replicates,
        "all_finite": finite,
        "noise": {
            "estimator": "ContinuousRLS",
            "P0": P0,
            "weights_true": w_a,
            "noise_std": sig,
            "bias": ea.mean(axis=1),
            "std": ea.std(axis=1, ddof=1),
            "std_predicted": np.sqrt(np.diag(unit_cov))[None, :] * sig[:, None],
        },
        "forgetting": {
            "estimator": "ForgettingRLS",
            "P0": P0_forgetting,
            "weights_before": w_a,
            "weights_after": w_b,
            "jump_time": float(t[jump]),
            "noise_std": forgetting_noise,
            "forgetting": lam,
            "bias": eb[:, 1:].mean(axis=1),
            "std": eb[:, 1:].std(axis=1, ddof=1),
            "time_to_1pct_after_jump": track,
        },
    }


def noise_figure(report: dict):
    """The noise study's figure: bias/spread against σ, and the forgetting-factor trade-off.

    **Arguments:** `report`, from [`noise_study`][].

    **Returns:** a `matplotlib.figure.Figure`, made without pyplot (the backend and pyplot's
    state are left alone).
    """
    from matplotlib.figure import Figure

    fig = Figure(figsize=(14, 4))
    a1, a2, a3 = fig.subplots(1, 3)
    nz = report["noise"]
    sig = np.asarray(nz["noise_std"])
    for j in range(3):
        (line,) = a1.loglog(sig, np.asarray(nz["std"])[:, j], "o-", ms=4, label=f"std ω̂{j + 1}")
        a1.loglog(sig, np.asarray(nz["std_predicted"])[:, j], ":", color=line.get_color())
        a1.loglog(sig, np.abs(np.asarray(nz["bias"])[:, j]), "x", color=line.get_color())
    a1.set(
        xlabel="noise std σ",
        ylabel="final estimate: std (o), |bias| (x)",
        title=f"continuous RLS, P0 = {nz['P0']:.0e}; dotted: closed form",
    )
    a1.legend(fontsize=8)
    fg = report["forgetting"]
    lam = np.asarray(fg["forgetting"])
    memory = 1.0 / np.maximum(1.0 - lam, 1e-4)
    std = np.linalg.norm(np.asarray(fg["std"]), axis=1)
    bias = np.linalg.norm(np.asarray(fg["bias"]), axis=1)
    a2.loglog(memory, std, "o-", ms=4, label="‖std‖ (noise)")
    a2.loglog(memory, np.maximum(bias, 1e-16), "s--", ms=4, label="‖bias‖ (old weights)")
    a2.set(
        xlabel="memory 1/(1 − λ) [samples]  (λ = 1 drawn at 1e4)",
        ylabel="final estimate",
        title=f"forgetting RLS after a weight jump, σ = {fg['noise_std']}",
    )
    a2.legend(fontsize=8)
    track = np.asarray(fg["time_to_1pct_after_jump"], float)
    ok = np.isfinite(track)
    a3.semilogx(memory[ok], track[ok], "o-", ms=4, label="re-converged")
    a3.semilogx(
        memory[~ok],
        np.full((~ok).sum(), report["duration"] - fg["jump_time"]),
        "^",
        color="C3",
        label="not within the record",
    )
    a3.set(xlabel="memory 1/(1 − λ) [samples]", ylabel="time to 1 % after the jump [s]", title="tracking (noise-free)")
    a3.legend(fontsize=8)
    fig.tight_layout()
    return fig
