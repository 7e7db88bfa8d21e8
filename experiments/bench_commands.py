"""Time and peak memory of the whole `piest fit` / `diagnose` / `estimate` command, defaults, across lengths.

    python experiments/bench_commands.py fit [--lengths 1e4,1e5,1e6,1e7]
        ->  experiments/results/bench_fit_command.json
    python experiments/bench_commands.py diagnose [--lengths 1e4,1e5,1e6]
        ->  experiments/results/bench_diagnose_command.json
    python experiments/bench_commands.py estimate [--lengths 1e4,1e5,1e6,1e7]
        ->  experiments/results/bench_estimate_command.json

The record is `bench_long_fit.py`'s (a plain four-play PI at 10 kHz, white noise σ = 0.01),
written to a CSV; the command then runs as a user runs it, in its own process (`piest fit
rec.csv`: the CSV read and checked, the structure chosen by held-out error, on the first 2^18
samples of a longer record, the chosen model fitted on every sample with its covariance, fit.json,
fit.md and fit.png written; `piest diagnose rec.csv`: the search, the refinement, the report;
`piest estimate rec.csv`: the paper's RLS with 20 uniform plays and an offset, streamed in
chunks, estimate.json and estimate.png written).
Wall time and the command process's peak resident memory (its `VmHWM`, polled; Linux), and what
the command concluded: the model chosen and its worst threshold error, or the effects named (none is right).
"""

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from bench_long_fit import R_TRUE, record

OUT = Path(__file__).parent / "results"


def _high_water_mb(pid: int) -> float | None:
    try:
        with open(f"/proc/{pid}/status") as f:
            return next(int(line.split()[1]) / 1024 for line in f if line.startswith("VmHWM"))
    except (OSError, StopIteration):
        return None


def _measured(argv):
    """Exit code, wall time, peak resident memory (MB) and stderr of a command.

    The peak is the command's own high-water mark (`VmHWM`), read every 20 ms until it exits. The
    children's `ru_maxrss` would also count the memory of this process at the fork (a forked
    child holds the parent's pages until it runs the command): with a long record generated
    here, hundreds of MB that the command never used.
    """
    t0 = time.perf_counter()
    with tempfile.TemporaryFile("w+") as err:
        proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=err, text=True)
        peak = 0.0
        while proc.poll() is None:
            peak = max(peak, _high_water_mb(proc.pid) or 0.0)
            time.sleep(0.02)
        secs = time.perf_counter() - t0
        err.seek(0)
        return proc.returncode, secs, peak, err.read()


def one(command: str, T: int, folder: Path) -> dict:
    t, u, y = record(T)
    csv = folder / f"rec_{T}.csv"
    np.savetxt(csv, np.column_stack([t, u, y]), delimiter=",", header="t,u,y", comments="", fmt="%.10g")
    del t, u, y
    out = folder / f"{command}_{T}"
    code, secs, peak, err = _measured(
        [sys.executable, "-m", "piest_jax", command, str(csv), "--out", str(out), "--quiet"]
    )
    csv.unlink()
    if code != 0:
        raise SystemExit(f"piest {command} on {T} samples: exit {code}: {err.strip()[-2000:]}")
    if command == "estimate":
        rep = json.loads((out / "estimate.json").read_text())
        return dict(
            n_samples=T,
            seconds=secs,
            seconds_per_sample=secs / T,
            peak_rss_mb=peak,
            final_rmse=rep["final_rmse"],
            all_exciting=rep["pe"]["all_exciting"],
        )
    if command == "diagnose":
        rep = json.loads((out / "report.json").read_text())
        return dict(
            n_samples=T,
            seconds=secs,
            seconds_per_sample=secs / T,
            peak_rss_mb=peak,
            effects=rep["effects"],
            baseline_rmse=rep["baseline_rmse"],
            heldout_baseline_rmse=rep["heldout"]["baseline_rmse"],
            noise_std=rep["noise_std_estimate"],
        )
    fit = json.loads((out / "fit.json").read_text())
    r = np.asarray(fit["thresholds"])
    row = dict(
        n_samples=T,
        seconds=secs,
        seconds_per_sample=secs / T,
        peak_rss_mb=peak,
        n_plays=fit["model"]["n_plays"],
        n_lags=fit["model"]["n_lags"],
        selection_samples=fit["selection"]["selection_samples"],
        thresholds=r.tolist(),
        rmse=fit["rmse"],
    )
    if len(r) == len(R_TRUE):
        row["max_threshold_error_rel"] = float(np.max(np.abs(r[1:] - R_TRUE[1:]) / np.array(R_TRUE[1:])))
    return row


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("command", choices=("fit", "diagnose", "estimate"))
    p.add_argument("--lengths", default="1e4,1e5,1e6,1e7")
    p.add_argument("--out", help="default: experiments/results/bench_<command>_command.json")
    args = p.parse_args(argv)
    args.out = args.out or str(OUT / f"bench_{args.command}_command.json")
    rows = []
    with tempfile.TemporaryDirectory() as d:
        for T in sorted(int(float(s)) for s in args.lengths.split(",")):
            rows.append(one(args.command, T, Path(d)))
            print(json.dumps(rows[-1]), flush=True)
    res = dict(
        machine=dict(cpus=os.cpu_count(), platform=platform.platform(), load_average=os.getloadavg()),
        command=f"piest {args.command} rec.csv --out DIR --quiet",
        runs=rows,
    )
    by_T = {r["n_samples"]: r for r in rows}
    if 100_000 in by_T and 1_000_000 in by_T:
        res["time_ratio_1e5_to_1e6"] = by_T[1_000_000]["seconds"] / by_T[100_000]["seconds"]
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(res, indent=1))
    print(args.out)


if __name__ == "__main__":
    main()
