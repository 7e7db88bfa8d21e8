"""What the covariance costs: `fit_pi` on 10^4 samples with and without it.

Each variant runs in a fresh process (so the first call includes compilation, as a `piest fit`
run does) and then three more times (the minimum is the warm time). Five plays, four starts,
float64, a noisy two-tone record.

Writes experiments/results/bench_fit_covariance.json.
Run: python experiments/bench_fit_covariance.py
"""

import json
import subprocess
import sys
from pathlib import Path

OUT = Path(__file__).parent / "results"

CHILD = r"""
import json, sys, time
import jax
jax.config.update("jax_enable_x64", True)
import numpy as np
import piest_jax as pj
method = None if sys.argv[1] == "none" else sys.argv[1]
n_lags = int(sys.argv[2])
T = 10_000
t = np.arange(T) * 1e-3
u = 2 * np.sin(2 * np.pi * t) + 0.7 * np.sin(2 * np.pi * 3.3 * t)
y = np.asarray(pj.PIOperator([0.0, 0.5, 1.1], [1.0, 0.6, 0.4], u[0])(u)) + 0.3
y = y + 0.01 * np.random.default_rng(0).standard_normal(T)
times = []
for _ in range(4):
    start = time.perf_counter()
    f = pj.fit_pi(u, y, 5, n_lags=n_lags, dt=1e-3, key=jax.random.key(0), covariance=method)
    jax.block_until_ready(f.thresholds)
    times.append(time.perf_counter() - start)
print(json.dumps({"first": times[0], "warm": min(times[1:])}))
"""


def main():
    results = {}
    for n_lags in (0, 2):
        for method in ("none", "newey-west", "none", "newey-west"):
            out = subprocess.run([sys.executable, "-c", CHILD, method, str(n_lags)], check=True,
                                 capture_output=True, text=True).stdout
            r = json.loads(out.strip().splitlines()[-1])
            key = f"lags={n_lags}/{method}"
            best = results.get(key, {"first": float("inf"), "warm": float("inf")})
            results[key] = {k: min(best[k], r[k]) for k in r}
            print(key, r)
        for k in ("first", "warm"):
            results[f"lags={n_lags}/ratio_{k}"] = (
                results[f"lags={n_lags}/newey-west"][k] / results[f"lags={n_lags}/none"][k])
    OUT.mkdir(exist_ok=True)
    (OUT / "bench_fit_covariance.json").write_text(json.dumps(results, indent=2) + "\n")
    print(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
