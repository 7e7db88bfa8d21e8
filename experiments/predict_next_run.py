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

On Aye, where the raw RMSE is mostly a level, `cycle_levels` asks whether the level follows the
loop's amplitude: the validation run's input sweeps its amplitude down to rest and back up, so
each whole cycle (maximum to maximum of the input) gives the measured mean output at one
amplitude, and each model's mean error there. Fitted against the cycle's squared half-range
relative to the largest (0 at rest, 1 at the largest loop), the slope is how far a model moves
its level between a loop at rest and the largest one, beside how far the device moves its own.

`aye_reverse` runs the Aye pair the other way (identify on the validation run, predict the
identification run): a level that belongs to the runs, not to a model, shows as mean errors of
opposite sign and like size in the two directions (`validation_mean_error`), whatever the model.
`slow_lag_level` is how much of the fitted model's level on the other run its slowest lag sets;
`diagnose_first_effect` is the reverse diagnosis stopped after the first effect it names.

Writes experiments/results/predict_next_run.json.
Run: python experiments/predict_next_run.py   (~8 min on 2 cores)
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


def aye_reverse_pair():
    ident, val = aye_pair()
    return val, ident


def fit_summary(rec, val) -> tuple[dict, np.ndarray]:
    """The summary, and the raw prediction of `val`."""
    t0 = time.perf_counter()
    ident = pj.identify(rec, val, key=jax.random.key(0))
    secs = time.perf_counter() - t0
    d = ident.to_json()
    keep = {k: d[k] for k in ("model", "rmse", "undetermined", "held_on_bounds", "creep", "std_errors") if k in d}
    keep["play_weight_sum"] = float(np.sum(d["weights"]))
    keep["selection"] = d["selection"]["models"]
    keep.update(
        {
            k: d[k]
            for k in (
                "validation_rmse",
                "validation_starts_at_rest",
                "validation_rmse_ic",
                "validation_outside_input_range",
                "validation_inside_input_range",
            )
            if k in d
        },
        seconds=secs,
    )
    pred = np.asarray(ident.validation.raw.prediction)
    keep["validation_mean_error"] = float(np.mean(pred - np.asarray(val.y)))
    return keep, pred


def diagnose_summary(rec, val, **options) -> tuple[dict, np.ndarray]:
    """The summary, and the final model's raw prediction of `val` (`options` for `pj.diagnose`)."""
    t0 = time.perf_counter()
    diagnosis = pj.diagnose(rec, val, **options)
    d = diagnosis.to_json()
    secs = time.perf_counter() - t0
    v = d["validation"]
    return {
        "effects": d["effects"],
        "parameters": d["parameters"],
        "final_rmse": d["final_rmse"],
        "validation_final_rmse": v["final_rmse"],
        "validation_final_rmse_ic": v["final_rmse_ic"],
        "validation_outside_input_range": v["outside_input_range"],
        "validation_inside_input_range": v["inside_input_range"],
        "validation_mean_error": float(np.mean(np.asarray(diagnosis.validation.final_prediction) - np.asarray(val.y))),
        "seconds": secs,
    }, np.asarray(diagnosis.validation.final_prediction)


def cycle_levels(val, predictions: dict) -> dict:
    """Per whole input cycle of `val` (maximum to maximum, from 1 s on): the input's half-range,
    the measured mean output and each prediction's mean error; and for each, the slope of the
    cycle means against the squared relative half-range (how far the level moves from a loop at
    rest to the largest one)."""
    t, u, y = (np.asarray(a) for a in (val.t, val.u, val.y))
    du = np.diff(u)
    peaks = np.flatnonzero((du[:-1] > 0) & (du[1:] <= 0)) + 1
    peaks = peaks[t[peaks] >= 1.0]
    cycles = [slice(a, b) for a, b in zip(peaks[:-1], peaks[1:], strict=True)]
    half = np.array([0.5 * np.ptp(u[c]) for c in cycles])
    out = {"half_range": half.tolist(), "measured_mean": [float(np.mean(y[c])) for c in cycles]}
    x = (half / half.max()) ** 2
    design = np.column_stack([np.ones_like(x), x])

    def slope(means) -> float:
        return float(np.linalg.lstsq(design, np.asarray(means), rcond=None)[0][1])

    out["slope_measured"] = slope(out["measured_mean"])
    for name, pred in predictions.items():
        err = [float(np.mean(np.asarray(pred)[c] - y[c])) for c in cycles]
        out[f"{name}_mean_error"] = err
        out[f"slope_{name}"] = slope(np.asarray(out["measured_mean"]) + err)
    return out


def slow_lag_level(fit: dict, rec, val) -> dict | None:
    """What the fitted model's slowest lag adds to its level on `val` against `rec`: a lag much
    slower than the input's cycles follows the run's mean input, so it moves the predicted level
    by its weight times the difference of the two runs' mean inputs (the offset took up the rest
    on `rec`)."""
    creep = fit.get("creep")
    if not creep:
        return None
    k = int(np.argmax(creep["time_constants"]))
    w = float(creep["weights"][k])
    return {
        "time_constant": float(creep["time_constants"][k]),
        "weight": w,
        "level_shift": w * float(np.mean(val.u) - np.mean(rec.u)),
    }


def main() -> None:
    RESULTS.mkdir(exist_ok=True)
    out = {"chandra_split": {"identify_before_s": SPLIT, "predict_until_s": END}, "aye": {}, "aye_reverse": {}}
    pairs = (("chandra_split", chandra_pair()), ("aye", aye_pair()), ("aye_reverse", aye_reverse_pair()))
    for name, (rec, val) in pairs:
        out[name]["n_samples"] = [rec.n_samples, val.n_samples]
        out[name]["fit"], fit_pred = fit_summary(rec, val)
        print(name, "fit", {k: out[name]["fit"].get(k) for k in ("model", "validation_rmse_ic", "seconds")})
        out[name]["diagnose"], diagnose_pred = diagnose_summary(rec, val)
        print(name, "diagnose", out[name]["diagnose"])
        if name == "aye":
            levels = cycle_levels(val, {"fit": fit_pred, "diagnose": diagnose_pred})
            out[name]["cycle_levels"] = levels
            print(name, "level slopes", {k: v for k, v in levels.items() if k.startswith("slope")})
        if name == "aye_reverse":
            # The diagnosis stopped after its first effect, to see what the second one adds.
            out[name]["diagnose_first_effect"], _ = diagnose_summary(rec, val, max_effects=1)
            print(name, "diagnose, first effect", out[name]["diagnose_first_effect"])
        if name.startswith("aye"):
            out[name]["input_mean"] = [float(np.mean(rec.u)), float(np.mean(val.u))]
            out[name]["slow_lag_level"] = slow_lag_level(out[name]["fit"], rec, val)
            print(name, "slow lag", out[name]["slow_lag_level"])
    pj.write_json(RESULTS / "predict_next_run.json", out)


if __name__ == "__main__":
    main()
