"""What the covariance costs: `fit_pi` on 10^4 samples with and without it.

Times are CPU seconds of the process (`time.process_time`, all threads), which other jobs on a
shared machine disturb far less than wall time. One process: the fit is compiled and run once
without covariance (`first_none`: compilation + solve, what a `piest fit` run pays), then once with
it (`first_covariance`: the solve + the Jacobian's own compilation; the fit's compilation is
shared). Then the two alternate `REPEATS` times, and the minimum of each is its warm time. The
cold ratio is (first_none + first_covariance - warm_covariance) / first_none: the time of a fresh
run with covariance over one without.

Five plays (and 0 or 2 creep lags), four starts, float64, a noisy two-tone record.
Writes experiments/results/bench_fit_covariance.json.
Run: python experiments/bench_fit_covariance.py
"""

import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np

import piest_jax as pj

OUT = Path(__file__).parent / "results"
T, REPEATS = 10_000, 5


def timed(fn):
    """CPU seconds of this process (all its threads): on a machine shared with other jobs, wall
    time measures their load as much as this fit."""
    start = time.process_time()
    jax.block_until_ready(fn().thresholds)
    return time.process_time() - start


def main():
    t = np.arange(T) * 1e-3
    u = 2 * np.sin(2 * np.pi * t) + 0.7 * np.sin(2 * np.pi * 3.3 * t)
    y = np.asarray(pj.PIOperator([0.0, 0.5, 1.1], [1.0, 0.6, 0.4], u[0])(u)) + 0.3
    y = y + 0.01 * np.random.default_rng(0).standard_normal(T)
    results = {"samples": T, "plays": 5, "starts": 4, "repeats": REPEATS}
    for n_lags in (0, 2):

        def fit(method):
            return pj.fit_pi(u, y, 5, n_lags=n_lags, dt=1e-3, key=jax.random.key(0), covariance=method)

        first_none = timed(lambda: fit(None))
        first_cov = timed(lambda: fit("newey-west"))
        warm = {None: [], "newey-west": []}
        for _ in range(REPEATS):
            for m in warm:
                warm[m].append(timed(lambda: fit(m)))
        w_none, w_cov = min(warm[None]), min(warm["newey-west"])
        r = {
            "first_none": first_none,
            "first_covariance": first_cov,
            "warm_none": w_none,
            "warm_covariance": w_cov,
            "ratio_warm": w_cov / w_none,
            "ratio_cold": (first_none + first_cov - w_cov) / first_none,
        }
        results[f"lags={n_lags}"] = r
        print(n_lags, {k: round(v, 3) for k, v in r.items()}, flush=True)
    OUT.mkdir(exist_ok=True)
    pj.write_json(OUT / "bench_fit_covariance.json", results)


if __name__ == "__main__":
    main()
