"""`piest diagnose` on measured piezo data: Aye (identification, validated on the validation run)
and Chandra (the at-rest start included). Writes experiments/results/diagnose_<name>/report.* and
experiments/results/diagnose_real_data.json.

    python experiments/diagnose_real_data.py
"""

import json
import os
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import piest_jax as pj  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "experiments" / "results"


def rel(path):
    """A path as the reports should show it: relative to the repository root."""
    return os.path.relpath(Path(path).resolve(), ROOT)


def one(name, data, validate=None):
    out = RESULTS / f"diagnose_{name}"
    argv = ["diagnose", rel(pj.dataset_path(data)), "--out", rel(out), "--force", "--quiet"]
    if validate:
        argv += ["--validate", rel(pj.dataset_path(validate))]
    t0 = time.time()
    rc = pj.run_cli(argv)
    secs = time.time() - t0
    rep = json.loads((out / "report.json").read_text())
    keep = {
        k: rep.get(k)
        for k in (
            "effects",
            "baseline_rmse",
            "final_rmse",
            "noise_std_estimate",
            "heldout",
            "validation",
            "n_samples",
            "search_step",
        )
    }
    keep["rounds"] = [
        {
            "best": r["best"],
            "named": r["named"],
            "current_heldout_rmse": r["current_heldout_rmse"],
            "candidates": r["candidates"],
        }
        for r in rep["rounds"]
    ]
    keep["where_structured"] = [w for w in rep["where"] if w["structured"]]
    keep.update(rc=rc, seconds=secs)
    return keep


def main_():
    # The CLI records the paths it is given; relative ones keep the reports free of this machine's
    # directories.
    os.chdir(ROOT)
    res = {
        "aye2018": one("aye2018", "piezo_aye2018_identification.csv", "piezo_aye2018_validation.csv"),
        "chandra2023": one("chandra2023", "piezo_chandra2023_1hz.csv"),
    }
    (RESULTS / "diagnose_real_data.json").write_text(json.dumps(res, indent=1))
    for k, v in res.items():
        val = v.get("validation") or {}
        print(
            k,
            v["effects"],
            "rmse",
            round(v["baseline_rmse"], 4),
            "->",
            round(v["final_rmse"], 4),
            "noise",
            round(v["noise_std_estimate"], 4),
            "validation",
            val.get("baseline_rmse"),
            "->",
            val.get("final_rmse"),
            f"{v['seconds']:.1f}s",
        )


if __name__ == "__main__":
    main_()
