"""Identify on one run, predict another: `piest fit` and `piest diagnose` with their defaults.

What a user of the shipped piezo records does first. Two pairs:

- **Chandra** (`piezo_chandra2023_1hz`): identify on the first 7 s, predict 7-9 s (the window
  Chandra et al. fit their sparse model on, 0.091 um in-sample). The validation stretch starts in
  motion, so its raw RMSE depends on states nobody recorded; `validation_rmse_ic` estimates the
  output offset and the plays' and lags' initial states on it, nothing else.
- **Aye** (`piezo_aye2018_identification` -> `piezo_aye2018_validation`): two runs of one device.

For each: `pj.identify` with its defaults (the model chosen by held-out error, the candidates
and scores tried, what was rejected as undetermined), its raw and IC validation RMSE, and
`pj.diagnose` on the same pair (its effects named and its `final_rmse_ic`). Float64, as the CLI.

Writes experiments/results/predict_next_run.json.
Run: python experiments/predict_next_run.py   (~4 min on 2 cores)
"""

import time
from pathlib import Path

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

import piest_jax as pj  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
SPLIT, END = 7.0, 9.0  # Chandra: identify before SPLIT s, predict SPLIT..END s


def chandra_pair():
    rec = pj.load_dataset("piezo_chandra2023_1hz")
    t = np.asarray(rec.t)
    i, j = int(np.searchsorted(t, SPLIT)), int(np.searchsorted(t, END, side="right"))
    return rec.slice(0, i), rec.slice(i, j)


def aye_pair():
    return pj.load_dataset("piezo_aye2018_identification"), pj.load_dataset("piezo_aye2018_validation")


def fit_summary(rec, val) -> dict:
    t0 = time.perf_counter()
    ident = pj.identify(rec, val, key=jax.random.key(0))
    secs = time.perf_counter() - t0
    d = ident.to_json()
    keep = {k: d[k] for k in ("model", "rmse", "undetermined", "held_on_bounds", "creep", "std_errors") if k in d}
    keep["selection"] = d["selection"]["models"]
    keep.update(
        {k: d[k] for k in ("validation_rmse", "validation_starts_at_rest", "validation_rmse_ic") if k in d},
        seconds=secs,
    )
    return keep


def diagnose_summary(rec, val) -> dict:
    t0 = time.perf_counter()
    d = pj.diagnose(rec, val).to_json()
    secs = time.perf_counter() - t0
    v = d["validation"]
    return {
        "effects": d["effects"],
        "final_rmse": d["final_rmse"],
        "validation_final_rmse": v["final_rmse"],
        "validation_final_rmse_ic": v["final_rmse_ic"],
        "seconds": secs,
    }


def main() -> None:
    RESULTS.mkdir(exist_ok=True)
    out = {"chandra_split": {"identify_before_s": SPLIT, "predict_until_s": END}, "aye": {}}
    for name, (rec, val) in (("chandra_split", chandra_pair()), ("aye", aye_pair())):
        out[name]["n_samples"] = [rec.n_samples, val.n_samples]
        out[name]["fit"] = fit_summary(rec, val)
        print(name, "fit", {k: out[name]["fit"].get(k) for k in ("model", "validation_rmse_ic", "seconds")})
        out[name]["diagnose"] = diagnose_summary(rec, val)
        print(name, "diagnose", out[name]["diagnose"])
    pj.write_json(RESULTS / "predict_next_run.json", out)


if __name__ == "__main__":
    main()
