"""Time and peak memory of a `piest fit --model pi --plays 4` fit from 10^3 to 10^7 samples.

    python experiments/bench_long_fit.py [--lengths 1e3,1e4,1e5,1e6,1e7]
        ->  experiments/results/bench_long_fit.json, experiments/results/bench_long_fit.png

The record is a plain four-play PI (thresholds 0, 0.2, 0.5, 0.8; weights 1, 0.5, 0.3, 0.2)
driven by an amplitude-modulated two-tone input sampled at 10 kHz, with white noise
(σ = 0.01) on the output. Each length is fitted in its own process, as the command line does
it (four starts, Levenberg-Marquardt, 100 steps at most, positive weights, float64); the wall
time includes JAX's start-up and compilation, and the peak memory is the process's maximum
resident set (`resource.getrusage`). Records longer than 2^16 samples are fitted by
normal equations accumulated chunk by chunk, shorter ones with the whole Jacobian in memory.
"""

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

R_TRUE = [0.0, 0.2, 0.5, 0.8]
W_TRUE = [1.0, 0.5, 0.3, 0.2]
SIGMA = 0.01
RATE = 10_000.0
OUT = Path(__file__).parent / "results"


def record(T: int):
    """The benchmark's record of T samples: (t, u, y) as NumPy arrays."""
    import numpy as np

    import piest_jax as pj

    t = np.arange(T) / RATE
    u = np.sin(2 * np.pi * 20 * t) * (0.7 + 0.3 * np.sin(2 * np.pi * 1.3 * t + 0.5)) + 0.3 * np.sin(2 * np.pi * 53 * t)
    y = np.asarray(pj.PIOperator(np.array(R_TRUE), np.array(W_TRUE), u[0])(u))
    return t, u, y + SIGMA * np.random.default_rng(0).standard_normal(T)


def one(T: int) -> dict:
    """Fit one record of T samples in this process; the measurements as a dict."""
    import resource

    t_start = time.perf_counter()
    import jax

    jax.config.update("jax_enable_x64", True)
    import numpy as np

    import piest_jax as pj

    t, u, y = record(T)
    rss_data = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    t0 = time.perf_counter()
    f = pj.fit_pi(u, y, 4, key=jax.random.key(0))
    jax.block_until_ready(f.thresholds)
    secs = time.perf_counter() - t0
    r = np.asarray(f.thresholds)
    return dict(
        n_samples=T,
        seconds=secs,
        seconds_per_sample=secs / T,
        seconds_with_startup=time.perf_counter() - t_start,
        peak_rss_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        rss_after_data_mb=rss_data,
        thresholds=r.tolist(),
        weights=np.asarray(f.weights).tolist(),
        max_threshold_error_rel=float(np.max(np.abs(r[1:] - R_TRUE[1:]) / np.array(R_TRUE[1:]))),
        rmse=float(f.rmse),
        result=f.result_name,
        steps=int(f.n_steps),
    )


def figure(rows, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    T = [r["n_samples"] for r in rows]
    fig, (a, b) = plt.subplots(1, 2, figsize=(9, 3.6))
    a.loglog(T, [r["seconds"] for r in rows], "o-", label="fit (compilation included)")
    a.loglog(T, [rows[-1]["seconds_per_sample"] * x for x in T], ":", label="linear in T")
    a.set(xlabel="samples", ylabel="wall time [s]", title="time")
    a.legend()
    b.loglog(T, [r["peak_rss_mb"] for r in rows], "o-", label="peak resident memory")
    b.loglog(T, [r["rss_after_data_mb"] for r in rows], "s--", label="before the fit")
    b.set(xlabel="samples", ylabel="MB", title="memory")
    b.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--lengths", default="1e3,1e4,1e5,1e6,1e7")
    p.add_argument("--one", type=int, help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.one:
        print(json.dumps(one(args.one)))
        return
    rows = []
    for T in (int(float(s)) for s in args.lengths.split(",")):
        out = subprocess.run([sys.executable, __file__, "--one", str(T)], capture_output=True, text=True, check=True)
        rows.append(json.loads(out.stdout.strip().splitlines()[-1]))
        print(json.dumps(rows[-1]), flush=True)
    res = dict(
        machine=dict(
            cpus=os.cpu_count(),
            platform=platform.platform(),
            processor=platform.processor(),
            load_average=os.getloadavg(),
        ),
        record=dict(thresholds=R_TRUE, weights=W_TRUE, noise_sigma=SIGMA, rate_hz=RATE),
        fits=rows,
    )
    by_T = {r["n_samples"]: r for r in rows}
    if 100_000 in by_T and 1_000_000 in by_T:
        res["time_ratio_1e5_to_1e6"] = by_T[1_000_000]["seconds"] / by_T[100_000]["seconds"]
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "bench_long_fit.json").write_text(json.dumps(res, indent=1))
    figure(rows, OUT / "bench_long_fit.png")


if __name__ == "__main__":
    main()
