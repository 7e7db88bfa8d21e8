"""Convergence of online weight estimation across inputs, weights, P0, noise and estimators.

One `piest_jax.run_batch` call (a single jitted `vmap`) runs every combination of

- input: u = A sin(2π·5t) ("sine") or u = A (sin(10πt) + 0.5 sin(2πt)) ("composite", A = 10 is
  the paper's Fig. 6 input), for a range of amplitudes A;
- true weights: `--replicates` random draws, each weight uniform in [0.5, 5];
- estimator: continuous RLS with P0 = 1e6 or 1e8, discrete RLS with forgetting λ = 0.995
  (P0 = 1e3, trace-capped), normalised gradient μ = 1;
- measurement noise σ = 0 or 0.1 on y,

on the paper's thresholds r = (0, 10/3, 20/3), dt = 1 ms, 2 s, Ŵ(0) = 0. For each input the PE
tools give, before any estimation, the Assumption 1 ratio ρ(T0) and the PE level c1 for T0 = 0.2 s
(one period of the 5 Hz component) and T0 = 1 s (one period of the slowest component).
The statistics per (input, estimator, σ) are the fraction of weight draws whose estimate settles
within 1 % of the truth, the median settling time (inf, null in JSON, when most never settle),
and the median final relative error
‖Ŵ − W‖ / ‖W‖.

Writes experiments/results/batch_convergence.json and .png.
Run: python experiments/batch_convergence.py [--replicates N] [--seed S] [--out DIR]
"""

import argparse
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import piest_jax as pj  # noqa: E402

OUT = Path(__file__).resolve().parent / "results"
R = np.array([0.0, 10.0 / 3.0, 20.0 / 3.0])
DT, DURATION = 1e-3, 2.0
# PE windows T0: one period of the 5 Hz component, and one of the slowest (1 Hz) component
WINDOWS = {"0.2 s": 200, "1 s": 1000}
AMPLITUDES = (3.0, 5.0, 6.0, 7.0, 8.0, 10.0, 12.0)
NOISE = (0.0, 0.1)
# (label, estimator, P0, forgetting λ, gradient μ)
CONFIGS = (
    ("continuous RLS, P0 = 1e6", "continuous", 1e6, 1.0, 1.0),
    ("continuous RLS, P0 = 1e8", "continuous", 1e8, 1.0, 1.0),
    ("forgetting RLS, λ = 0.995", "forgetting", 1e3, 0.995, 1.0),
    ("normalised gradient, μ = 1", "gradient", 1.0, 1.0, 1.0),
)


def inputs(t: np.ndarray) -> tuple[list[str], np.ndarray]:
    """Every input of the study: names and signals (n_inputs, T)."""
    names, signals = [], []
    for kind in ("sine", "composite"):
        for a in AMPLITUDES:
            names.append(f"{kind} A = {a:g}")
            if kind == "sine":
                signals.append(a * np.sin(2 * np.pi * 5 * t))
            else:
                signals.append(a * (np.sin(10 * np.pi * t) + 0.5 * np.sin(2 * np.pi * t)))
    return names, np.stack(signals)


def excitation(u: np.ndarray, window: int) -> tuple[np.ndarray, np.ndarray]:
    """ρ(T0) and c1 of every input, one `vmap` each; the regressor does not depend on weights."""
    U = jnp.asarray(u)
    rho = jax.vmap(lambda x: pj.assumption1_ratio(x, R[-1], window))(U)
    c1 = jax.vmap(lambda x: pj.pe_level(pj.play(x, jnp.asarray(R)), window))(U)
    return np.asarray(rho), np.asarray(c1)


def study(*, key, replicates: int) -> dict:
    t = np.arange(int(round(DURATION / DT)) + 1) * DT
    T = len(t)
    names, u = inputs(t)
    pe = {name: excitation(u, w) for name, w in WINDOWS.items()}
    k_w, k_noise = jax.random.split(key)
    weights = np.asarray(jax.random.uniform(k_w, (replicates, 3), minval=0.5, maxval=5.0))
    # members in the order (input, config, noise, replicate)
    shape = (len(names), len(CONFIGS), len(NOISE), replicates)
    i_in, i_cfg, i_sig, i_rep = (a.ravel() for a in np.indices(shape))
    cfg = [CONFIGS[i] for i in i_cfg]
    t0 = time.perf_counter()
    stats = pj.run_batch(
        u[i_in],
        weights[i_rep],
        R,
        key=k_noise,
        estimator=[c[1] for c in cfg],
        P0=np.array([c[2] for c in cfg]),
        forgetting=np.array([c[3] for c in cfg]),
        gain=np.array([c[4] for c in cfg]),
        noise_std=np.asarray(NOISE)[i_sig],
        dt=DT,
    )
    jax.block_until_ready(stats)
    seconds = time.perf_counter() - t0
    settle = np.asarray(stats.settle_index).reshape(shape)
    rel = np.linalg.norm(np.asarray(stats.final_error), axis=1) / np.linalg.norm(weights[i_rep], axis=1)
    rel = rel.reshape(shape)
    settled = settle < T
    # median over all draws, counting a draw that never settles as inf
    median_time = np.median(np.where(settled, settle * DT, np.inf), axis=-1)
    return {
        "setting": "r = (0, 10/3, 20/3), dt = 1 ms, 2 s, W(0) = 0, weights uniform in [0.5, 5]",
        "members": int(np.prod(shape)),
        "batch_seconds": seconds,
        "all_finite": bool(np.all(np.asarray(stats.finite))),
        "replicates": replicates,
        "inputs": names,
        "assumption1_ratio": {name: v[0] for name, v in pe.items()},
        "pe_level_c1": {name: v[1] for name, v in pe.items()},
        "estimators": [c[0] for c in CONFIGS],
        "noise_std": list(NOISE),
        "axes": ["input", "estimator", "noise_std"],
        "fraction_settled_1pct": settled.mean(-1),
        "median_time_to_1pct": median_time,
        "median_final_rel_error": np.median(rel, axis=-1),
    }


def figure(rep: dict):
    """Final error against ρ(T0 = 1 s) for each input family, and the fraction that settles."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rho = np.asarray(rep["assumption1_ratio"]["1 s"])
    err = np.asarray(rep["median_final_rel_error"])
    frac = np.asarray(rep["fraction_settled_1pct"])
    n_amp = len(AMPLITUDES)
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    for k, kind in enumerate(("sine", "composite")):
        sl = slice(k * n_amp, (k + 1) * n_amp)
        for j, label in enumerate(rep["estimators"]):
            for s, sigma in enumerate(rep["noise_std"]):
                style = dict(color=f"C{j}", ls="-" if s == 0 else "--", marker="os"[k], ms=4)
                lab = f"{label}, σ = {sigma:g}" if k == 0 else None
                axes[k].semilogy(rho[sl], np.maximum(err[sl, j, s], 1e-16), label=lab, **style)
                axes[2].plot(rho[sl], frac[sl, j, s], **style)
        axes[k].axvline(1.0, color="k", lw=0.6, ls=":")
        axes[k].set(
            xlabel="Assumption 1 ratio ρ(T0 = 1 s)",
            ylabel="median ‖Ŵ − W‖/‖W‖ at 2 s",
            title=f"{kind} inputs, A = {min(AMPLITUDES):g}..{max(AMPLITUDES):g}",
        )
    axes[0].legend(fontsize=7)
    axes[2].axvline(1.0, color="k", lw=0.6, ls=":")
    axes[2].set(
        xlabel="Assumption 1 ratio ρ(T0 = 1 s)",
        ylabel="fraction of weight draws",
        title="within 1 % from some time on (o sine, s composite)",
    )
    fig.tight_layout()
    return fig


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--replicates", type=int, default=16, help="weight draws per setting")
    p.add_argument("--seed", type=int, default=0, help="PRNG seed (weights and noise)")
    p.add_argument("--out", type=Path, default=OUT, help="output folder")
    args = p.parse_args(argv)
    if args.replicates < 1:
        p.error("--replicates must be at least 1")
    t0 = time.perf_counter()
    rep = study(key=jax.random.PRNGKey(args.seed), replicates=args.replicates)
    rep["seed"] = args.seed
    rep["runtime_s"] = time.perf_counter() - t0
    args.out.mkdir(parents=True, exist_ok=True)
    print(pj.save_figure(figure(rep), args.out / "batch_convergence.png", dpi=120))
    print(pj.write_json(args.out / "batch_convergence.json", rep))
    return 0


if __name__ == "__main__":
    sys.exit(main())
