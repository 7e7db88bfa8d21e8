"""Preisach and generalized PI vs plain PI on the shipped B-H loops: fit on some loops, predict a
held-out one.

Each `bh_szewczyk2016_*` file holds closed symmetric loops at several amplitudes (H the input,
B the output), every loop starting at +H_max. For every interior loop (neither the smallest nor the
largest, so the prediction interpolates in amplitude), the models are fitted on the other loops and
predict the held-out one. The loops are concatenated in increasing amplitude, each played twice
with the first pass masked out, so every fitted or predicted loop is in its periodic steady state
(the plays' memory comes from the previous pass of the same loop, as in a measurement of
repeated cycles). Every play starts demagnetised (state 0, the loops are symmetric about H = 0):
that is the state after rising from a demagnetised core to +H_max, and, because the loops come in
increasing amplitude, also the state the plays wider than a loop still hold from the smaller ones.

Models: a plain 20-play least-squares PI with signed weights (`pj.uniform_pi`, the issue's
baseline) and a discrete Preisach model (`pj.fit_preisach`, smoothness chosen on held-out blocks
of the training record), with a signed density and with a non-negative one (`monotone=True`: B
non-decreasing in H for a fixed past, which also makes the model invertible), and a generalized
PI (`pj.fit_gpi`: 8 plays with fitted thresholds, then the saturating output function with its
default 2 tanh terms) next to an 8-play PI fitted the same way (`pj.fit_pi`), which separates
what the output function adds from what fitted thresholds add. Writes
experiments/results/preisach_bh.json and preisach_bh.png.

The generalized PI's settings were chosen before looking at these records' scores: 8 plays is
the play count `piest fit` keeps on the Aye piezo record, and with the loops' saturation taken
by the output function the plays only shape the loops' widths; 2 terms is `fit_gpi`'s default.

    python experiments/preisach_bh.py
"""

import json
import time
from pathlib import Path

import jax
import numpy as np

import piest_jax as pj

jax.config.update("jax_enable_x64", True)  # as the CLI: the fits in float64

OUT = Path(__file__).resolve().parent / "results"
N_PLAYS = 20
N_PLAYS_FITTED = 8  # the generalized PI's and the fitted PI's plays
GRID = (16, 16)  # half-widths × centres; the training records have 260-390 fitted samples


def loops(name):
    data = np.loadtxt(pj.dataset_path(name), delimiter=",", skiprows=1)
    return [(data[data[:, 0] == k, 1], data[data[:, 0] == k, 2]) for k in np.unique(data[:, 0])]


def twice(parts):
    """Each (H, B) loop played twice; the mask keeps only the second pass."""
    u = np.concatenate([np.concatenate([h, h]) for h, _ in parts])
    y = np.concatenate([np.concatenate([b, b]) for _, b in parts])
    mask = np.concatenate([np.r_[np.zeros(len(h)), np.ones(len(h))] for h, _ in parts])
    return u, y, mask


def rmse(a, b):
    return float(np.sqrt(np.mean((np.asarray(a) - np.asarray(b)) ** 2)))


def main():
    results, curves = [], []
    for name in [n for n in pj.datasets() if n.startswith("bh_")]:
        all_loops = loops(name)
        for held in range(1, len(all_loops) - 1):
            train = [lp for k, lp in enumerate(all_loops) if k != held]
            u, y, mask = twice(train)
            h, b = all_loops[held]
            v = np.concatenate([h, h])

            t0 = time.perf_counter()
            pi = pj.uniform_pi(u, y, N_PLAYS, initial_states=0.0, mask=mask)
            t_pi = time.perf_counter() - t0
            pi_pred = np.asarray(pi(v, initial_states=np.zeros(N_PLAYS)))[len(h) :]

            t0 = time.perf_counter()
            # The smoothness by the default held-out blocks (5 contiguous blocks of the training
            # record; blocks aligned with the loops, n_blocks=len(train), chose worse here: with
            # 2-3 training loops that scores mostly extrapolation to the largest loop).
            pre = pj.fit_preisach(u, y, n_widths=GRID[0], n_centres=GRID[1], mask=mask, initial_states=0.0)
            t_pre = time.perf_counter() - t0
            pre_pred = np.asarray(pre.model(v))[len(h) :]

            t0 = time.perf_counter()
            mono = pj.fit_preisach(
                u, y, n_widths=GRID[0], n_centres=GRID[1], mask=mask, initial_states=0.0, monotone=True
            )
            t_mono = time.perf_counter() - t0
            mono_pred = np.asarray(mono.model(v))[len(h) :]

            t0 = time.perf_counter()
            gpi = pj.fit_gpi(u, y, N_PLAYS_FITTED, initial_states=0.0, mask=mask, key=jax.random.key(0))
            t_gpi = time.perf_counter() - t0
            gpi_pred = np.asarray(gpi(v, np.zeros(N_PLAYS_FITTED)))[len(h) :]
            fpi = pj.fit_pi(u, y, N_PLAYS_FITTED, initial_states=0.0, mask=mask, key=jax.random.key(0), covariance=None)
            fpi_pred = np.asarray(fpi(v, np.zeros(N_PLAYS_FITTED)))[len(h) :]

            e_pi, e_pre, e_mono = rmse(pi_pred, b), rmse(pre_pred, b), rmse(mono_pred, b)
            e_gpi, e_fpi = rmse(gpi_pred, b), rmse(fpi_pred, b)
            row = {
                "dataset": name,
                "held_out_loop": held,
                "H_max": float(np.max(h)),
                "B_range": float(np.ptp(b)),
                "pi20_rmse_T": e_pi,
                "preisach_rmse_T": e_pre,
                "ratio_preisach_over_pi": e_pre / e_pi,
                "preisach_monotone_rmse_T": e_mono,
                "ratio_preisach_monotone_over_pi": e_mono / e_pi,
                "gpi_rmse_T": e_gpi,
                "ratio_gpi_over_pi": e_gpi / e_pi,
                "pi_fitted_rmse_T": e_fpi,
                "ratio_pi_fitted_over_pi": e_fpi / e_pi,
                "gpi_train_rmse_T": float(gpi.rmse),
                "gpi_result": gpi.result_name,
                "pi_fitted_train_rmse_T": float(fpi.rmse),
                "fit_seconds_gpi": t_gpi,
                "pi20_train_rmse_T": float(pi.rmse),
                "preisach_train_rmse_T": pre.rmse,
                "preisach_monotone_train_rmse_T": mono.rmse,
                "preisach_smoothness": pre.smoothness,
                "preisach_monotone_smoothness": mono.smoothness,
                "fit_seconds_pi": t_pi,
                "fit_seconds_preisach": t_pre,
                "fit_seconds_preisach_monotone": t_mono,
            }
            results.append(row)
            curves.append((name, held, h, b, pi_pred, pre_pred, mono_pred, gpi_pred))
            print(
                f"{name} loop {held} (H_max {row['H_max']:.4g}): PI20 {e_pi:.4g} T, "
                f"Preisach {e_pre:.4g} T (ratio {e_pre / e_pi:.3f}), monotone Preisach "
                f"{e_mono:.4g} T (ratio {e_mono / e_pi:.3f}), GPI {e_gpi:.4g} T (ratio "
                f"{e_gpi / e_pi:.3f}), PI{N_PLAYS_FITTED} fitted {e_fpi:.4g} T",
                flush=True,
            )

    summary = {"grid": list(GRID), "n_plays_pi": N_PLAYS, "n_plays_fitted": N_PLAYS_FITTED, "cases": results}
    for key in ("preisach", "preisach_monotone", "gpi", "pi_fitted"):
        ratios = np.array([r[f"ratio_{key}_over_pi"] for r in results])
        summary[key] = {
            "median_ratio": float(np.median(ratios)),
            "geometric_mean_ratio": float(np.exp(np.mean(np.log(ratios)))),
            "worst_ratio": float(np.max(ratios)),
        }
    pj.write_json(OUT / "preisach_bh.json", summary)
    print(json.dumps({k: v for k, v in summary.items() if k != "cases"}, indent=1))

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(curves), figsize=(3.2 * len(curves), 3.2))
    for ax, (name, held, h, b, p1, p2, p3, p4) in zip(np.atleast_1d(axes), curves):
        ax.plot(h, b, "k", lw=2, label="measured")
        ax.plot(h, p1, "C0--", lw=1, label=f"PI {N_PLAYS} plays")
        ax.plot(h, p2, "C3:", lw=1, label="Preisach")
        ax.plot(h, p3, "C2", lw=1, label="Preisach, μ ≥ 0")
        ax.plot(h, p4, "C4-.", lw=1, label=f"generalized PI, {N_PLAYS_FITTED} plays")
        ax.set_title(f"{name.removeprefix('bh_szewczyk2016_')}\nloop {held} held out", fontsize=8)
        ax.set_xlabel("H [A/m]")
    np.atleast_1d(axes)[0].set_ylabel("B [T]")
    np.atleast_1d(axes)[0].legend(fontsize=7)
    fig.tight_layout()
    pj.save_figure(fig, OUT / "preisach_bh.png")


if __name__ == "__main__":
    main()
