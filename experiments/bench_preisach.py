"""Time of `pj.fit_preisach` at 10^4 and 10^5 samples, 20 × 20 and 30 × 30 grids.

The input is a random sequence of reversal points (every tenth pair a full excursion), 50 samples
per leg, and the output tanh(2u) plus noise; the smoothness is chosen on 5 held-out blocks (9
candidates), the default, and so is the density's Newey-West covariance. Each row is the minimum
over repeats after one warm-up call that also compiles the accumulation (`first_call_seconds`
keeps that call), wall clock, on whatever CPU this runs on (the JSON records the core count).

Run: python experiments/bench_preisach.py [--repeats N]
"""

import argparse
import os
import time
from pathlib import Path

import numpy as np

import piest_jax as pj

OUT = Path(__file__).resolve().parent / "results" / "bench_preisach.json"


def record(T, rng):
    pts = rng.uniform(-1, 1, T // 50 + 2)
    pts[::10], pts[1::10] = -1.0, 1.0
    u = np.concatenate([np.linspace(a, b, 50, endpoint=False) for a, b in zip(pts[:-1], pts[1:])])
    u = u[:T]
    return u, np.tanh(2 * u) + 0.01 * rng.normal(size=T)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=2)
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    rows = []
    for T in (10_000, 100_000):
        u, y = record(T, rng)
        for K, M in ((20, 20), (30, 30)):
            t0 = time.perf_counter()
            fit = pj.fit_preisach(u, y, n_widths=K, n_centres=M)
            first = time.perf_counter() - t0
            times = []
            for _ in range(args.repeats):
                t0 = time.perf_counter()
                pj.fit_preisach(u, y, n_widths=K, n_centres=M)
                times.append(time.perf_counter() - t0)
            rows.append(
                {
                    "samples": T,
                    "grid": [K, M],
                    "seconds": min(times),
                    "first_call_seconds": first,
                    "rmse": fit.rmse,
                    "smoothness": fit.smoothness,
                }
            )
            print(rows[-1], flush=True)
    pj.write_json(OUT, {"cpu_count": os.cpu_count(), "load_average": os.getloadavg(), "rows": rows})


if __name__ == "__main__":
    main()
