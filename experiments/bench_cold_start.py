"""Start-up cost of every `piest` command: without the compilation cache, first and second run.

    python experiments/bench_cold_start.py     # results/bench_cold_start.json (~6 min on 2 cores)
    python experiments/bench_cold_start.py --only reproduce   # re-measures one, keeps the rest

Each command runs as a user runs it (`python -m piest_jax ...`, its own process) three times:
with the cache off (`PIEST_COMPILE_CACHE=off`), then twice with an empty cache folder of its own
(the first run fills it, the second finds it). The floor is the bare `python -c "import jax"`.
A command's invocation is the one `docs/figures/make_figures.sh` draws the README's figure with
(the shipped Aye piezo runs); `compensate` inverts a plain PI fitted beforehand, untimed.
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

import piest_jax as pj

OUT = Path(__file__).parent / "results" / "bench_cold_start.json"


def commands(model: Path) -> dict[str, list[str]]:
    ident = str(pj.dataset_path("piezo_aye2018_identification.csv"))
    val = str(pj.dataset_path("piezo_aye2018_validation.csv"))
    return {
        "simulate": ["simulate"],
        "reproduce": ["reproduce", "all"],
        "montecarlo": ["montecarlo", "--inputs", "2100", "--samples", "2000", "--plays", "6", "--seed", "0"],
        "excite": ["excite", "--thresholds", "0,3.3333,6.6667", "--amplitude", "10", "--samples", "5000"],
        "estimate": ["estimate", ident],
        "fit": ["fit", ident, "--validate", val],
        "compensate": ["compensate", str(model), val],
        "diagnose": ["diagnose", ident, "--validate", val],
    }


def timed(argv, env, cwd) -> float:
    t0 = time.perf_counter()
    proc = subprocess.run(argv, env=env, cwd=cwd, capture_output=True, text=True)
    secs = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(argv)}: exit {proc.returncode}: {proc.stderr.strip()[-2000:]}")
    return secs


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", default="", help="comma-separated commands (default: all)")
    ap.add_argument("--out", type=Path, default=OUT)
    a = ap.parse_args()
    base = {k: v for k, v in os.environ.items() if not k.startswith(("JAX_", "PIEST_"))}
    base["MPLBACKEND"] = "Agg"
    py = [sys.executable, "-m", "piest_jax"]
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        off = {**base, "PIEST_COMPILE_CACHE": "off"}
        floor = min(timed([sys.executable, "-c", "import jax"], off, work) for _ in range(3))
        helps = min(timed([*py, "--help"], off, work) for _ in range(3))
        model = work / "model"
        cmds = commands(model / "fit.json")
        timed([*py, *cmds["fit"][:2], "--model", "pi", "--plays", "auto", "--out", str(model), "--quiet"], off, work)
        # `--only` re-measures some commands and keeps the others' rows, each with its own floor.
        rows = {}
        if a.only and a.out.exists():
            kept = json.loads(a.out.read_text())
            rows = {k: {"floor_s": kept["import_jax_floor_s"], **r} for k, r in kept["commands"].items()}
        for name in [c for c in a.only.split(",") if c] or list(cmds):
            argv = [*py, *cmds[name], "--quiet", "--force"]
            cached = {**base, "PIEST_COMPILE_CACHE": str(work / f"cache-{name}")}
            row = {"argv": ["piest", *argv[3:]]}
            row["off_s"] = timed([*argv, "--out", str(work / f"{name}-off")], off, work)
            row["first_s"] = timed([*argv, "--out", str(work / f"{name}-1")], cached, work)
            row["second_s"] = timed([*argv, "--out", str(work / f"{name}-2")], cached, work)
            entries = list((work / f"cache-{name}").iterdir())
            row["cache_entries"] = len(entries)
            row["cache_mb"] = sum(e.stat().st_size for e in entries) / 2**20
            row["floor_s"] = floor
            row["second_over_floor"] = row["second_s"] / floor
            rows[name] = row
            print(
                f"{name:11s} off {row['off_s']:6.1f} s  first {row['first_s']:6.1f} s  "
                f"second {row['second_s']:6.1f} s  ({row['second_over_floor']:.1f}x the floor)",
                flush=True,
            )
    report = {
        "machine": {"platform": platform.platform(), "cpus": os.cpu_count(), "python": platform.python_version()},
        "import_jax_floor_s": floor,
        "help_s": helps,
        "commands": rows,
    }
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(report, indent=2) + "\n")
    print(f"floor (import jax) {floor:.2f} s, piest --help {helps:.2f} s -> {a.out}")


if __name__ == "__main__":
    main()
