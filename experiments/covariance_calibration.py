"""Are the fit's standard errors right? Predicted against observed spread over noise draws.

A three-play PI model with an offset (known thresholds, weights, offset) is driven by a decaying
sine of 300 samples; each draw adds fresh noise to its output and fits it again. For every fitted
parameter the experiment compares the mean predicted standard error with the standard deviation of
the estimates over the draws (the ratio should lie in 0.8-1.25), and counts how often the 95 %
interval (estimate ± 1.96 std errors) covers the true value.

Two noises: white (σ = 1 % of the output range), where both estimates should be calibrated, and
AR(1) with ρ = 0.95 (the same marginal σ), like a measured record's model error, where the
Gauss-Newton σ²(JᵀJ)⁻¹ assumes independent samples and comes out too small, while the Newey-West
sandwich (piest_jax's default) stays close.

The prediction bands (`pj.prediction_band`) are checked the same way: over the draws, the
fraction of samples where the 95 % band of the mean prediction holds the noiseless output, and
where the 95 % measurement band holds a fresh noisy output (a second draw of the same noise).

Writes experiments/results/covariance_calibration.json and covariance_calibration.png.
Run: python experiments/covariance_calibration.py [--draws N]
"""

import argparse
import time
from pathlib import Path

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

import piest_jax as pj

OUT = Path(__file__).parent / "results"
R, W, C = np.array([0.0, 0.4, 0.9]), np.array([1.0, 0.6, 0.5]), 0.3
METHODS = ("newey-west", "gauss-newton")


def noise(kind, rng, shape, sd):
    e = rng.standard_normal(shape)
    if kind == "ar1":
        rho = 0.95
        for t in range(1, shape[1]):
            e[:, t] = rho * e[:, t - 1] + np.sqrt(1 - rho**2) * e[:, t]
    return sd * e


def run(draws: int, T: int = 300):
    t = np.linspace(0.0, 2.0, T)
    u = 1.5 * np.sin(2 * np.pi * 2 * t) * (1 - 0.2 * t)
    y0 = np.asarray(pj.PIOperator(R, W, u[0])(u)) + C
    truth = np.concatenate([R[1:], W, [C]])
    results = {}
    for kind in ("white", "ar1"):
        rng = np.random.default_rng(2026)
        e = noise(kind, rng, (draws, T), 0.01 * np.ptp(y0))
        fresh = noise(kind, rng, (draws, T), 0.01 * np.ptp(y0))
        for method in METHODS:
            start = time.perf_counter()
            est, se, mean_cover, new_cover = [], [], [], []
            for k in range(draws):
                f = pj.fit_pi(u, y0 + e[k], 3, thresholds0=R, n_starts=1, covariance=method)
                est.append(np.asarray(f.parameter_values))
                se.append(np.asarray(f.std_errors))
                band = pj.prediction_band(f, u)
                mean_cover.append(band.coverage(y0, measurement=False))
                new_cover.append(band.coverage(y0 + fresh[k]))
            est, se = np.array(est), np.array(se)
            spread = est.std(axis=0, ddof=1)
            covered = np.abs(est - truth) <= 1.96 * se
            results[f"{kind}/{method}"] = {
                "parameters": list(f.parameter_names),
                "mean_std_error": se.mean(axis=0),
                "spread": spread,
                "ratio": se.mean(axis=0) / spread,
                "coverage_95": covered.mean(axis=0),
                # Fractions of samples (over all draws) inside the 95 % bands, and their spread
                # over the draws.
                "band_coverage_mean": float(np.mean(mean_cover)),
                "band_coverage_mean_draw_range": [float(np.min(mean_cover)), float(np.max(mean_cover))],
                "band_coverage_measurement": float(np.mean(new_cover)),
                "seconds": time.perf_counter() - start,
            }
            print(
                kind,
                method,
                np.round(se.mean(axis=0) / spread, 3),
                np.round(covered.mean(axis=0), 3),
                "bands:",
                round(float(np.mean(mean_cover)), 3),
                round(float(np.mean(new_cover)), 3),
            )
    return results


def figure(results):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(15, 4), gridspec_kw={"width_ratios": [3, 3, 2]})
    for ax, kind in zip(axes, ("white", "ar1")):
        for i, method in enumerate(METHODS):
            r = results[f"{kind}/{method}"]
            x = np.arange(len(r["parameters"])) + (i - 0.5) * 0.35
            ax.bar(x, r["ratio"], width=0.35, label=method)
        ax.axhspan(0.8, 1.25, color="0.9", zorder=0, label="0.8-1.25")
        ax.axhline(1.0, color="k", lw=0.6)
        ax.set_xticks(np.arange(len(r["parameters"])), r["parameters"], rotation=45, ha="right", fontsize=8)
        ax.set(
            title=f"{'white noise' if kind == 'white' else 'AR(1) noise, rho = 0.95'}",
            ylabel="predicted std error / observed spread",
        )
        ax.legend(fontsize=8)
    # The bands' coverage: mean prediction (noiseless output) and new measurement, per noise.
    ax = axes[2]
    labels = [f"{k}\n{b}" for k in ("white", "ar1") for b in ("mean", "measurement")]
    for i, method in enumerate(METHODS):
        cov = [
            results[f"{k}/{method}"][f"band_coverage_{b}"] for k in ("white", "ar1") for b in ("mean", "measurement")
        ]
        ax.bar(np.arange(4) + (i - 0.5) * 0.35, cov, width=0.35, label=method)
    ax.axhspan(0.90, 0.98, color="0.9", zorder=0, label="0.90-0.98")
    ax.axhline(0.95, color="k", lw=0.6)
    ax.set_xticks(np.arange(4), labels, fontsize=8)
    ax.set(ylim=(0, 1.05), title="95 % prediction bands", ylabel="fraction of samples inside")
    ax.legend(fontsize=8, loc="lower left")
    fig.tight_layout()
    return fig


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--draws", type=int, default=300)
    args = p.parse_args()
    results = run(args.draws)
    OUT.mkdir(exist_ok=True)
    pj.write_json(
        OUT / "covariance_calibration.json",
        {"draws": args.draws, "samples": 300, "noise_sd_fraction_of_range": 0.01, "results": results},
    )
    pj.save_figure(figure(results), OUT / "covariance_calibration.png", dpi=110)


if __name__ == "__main__":
    main()
