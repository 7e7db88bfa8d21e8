"""Time and peak memory of the whole `piest fit rec.csv` command, defaults, across record lengths.

    python experiments/bench_fit_command.py [--lengths 1e4,1e5,1e6,1e7]
        ->  experiments/results/bench_fit_command.json

The record is `bench_long_fit.py`'s (a plain four-play PI at 10 kHz, white noise σ = 0.01),
written to a CSV; the command then runs as a user runs it, in its own process: the CSV read and
checked, the structure chosen (plays, and creep or not, by held-out error: on the first 2^18
samples of a longer record), the chosen model fitted on every sample with its covariance, fit.json,
fit.md and fit.png written. Wall time and the command process's peak resident memory
(`resource.getrusage(RUSAGE_CHILDREN)`), the model chosen and its worst threshold error.
"""

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from bench_long_fit import R_TRUE, record

OUT = Path(__file__).parent / "results"


def one(T: int, folder: Path) -> dict:
    t, u, y = record(T)
    csv = folder / f"rec_{T}.csv"
    np.savetxt(csv, np.column_stack([t, u, y]), delimiter=",", header="t,u,y", comments="", fmt="%.10g")
    out = folder / f"fit_{T}"
    # Each length in a fresh process; the children's peak is the largest so far, so lengths run
    # from the shortest up and the figure for each is the running maximum.
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "piest_jax", "fit", str(csv), "--out", str(out), "--quiet"],
                          capture_output=True, text=True)
    secs = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"piest fit on {T} samples: exit {proc.returncode}: {proc.stderr.strip()[-2000:]}")
    fit = json.loads((out / "fit.json").read_text())
    r = np.asarray(fit["thresholds"])
    row = dict(n_samples=T, seconds=secs, seconds_per_sample=secs / T,
               peak_rss_mb=resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024,
               csv_mb=csv.stat().st_size / 2**20, n_plays=fit["model"]["n_plays"], n_lags=fit["model"]["n_lags"],
               selection_samples=fit["selection"]["selection_samples"], thresholds=r.tolist(),
               rmse=fit["rmse"])
    if len(r) == len(R_TRUE):
        row["max_threshold_error_rel"] = float(np.max(np.abs(r[1:] - R_TRUE[1:]) / np.array(R_TRUE[1:])))
    csv.unlink()
    return row


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--lengths", default="1e4,1e5,1e6,1e7")
    p.add_argument("--out", default=str(OUT / "bench_fit_command.json"))
    args = p.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory() as d:
        for T in sorted(int(float(s)) for s in args.lengths.split(",")):
            rows.append(one(T, Path(d)))
            print(json.dumps(rows[-1]), flush=True)
    res = dict(machine=dict(cpus=os.cpu_count(), platform=platform.platform(), load_average=os.getloadavg()),
               command="piest fit rec.csv --out DIR --quiet", fits=rows)
    by_T = {r["n_samples"]: r for r in rows}
    if 100_000 in by_T and 1_000_000 in by_T:
        res["time_ratio_1e5_to_1e6"] = by_T[1_000_000]["seconds"] / by_T[100_000]["seconds"]
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(res, indent=1))
    print(args.out)


if __name__ == "__main__":
    main()
