"""Should `piest fit --model auto` also try the models that saturate? A measurement on the piezo records.

`--model auto` chooses plain PI or PI + creep by the held-out error on the last 30 % of the
identification record. This script fits a discrete Preisach model (16 x 16 grid, density >= 0 and
signed, `pj.fit_preisach`) and a generalized PI (8 plays, 2 output terms, `pj.fit_gpi`) on the
same first 70 % and scores them on the same last 30 %, then fits them on the whole record and
runs them on the Aye validation run, next to the default model's raw
validation RMSE (`pj.identify` with its defaults). If the held-out block chose these models where
they predict the other run worse, adding them to `auto` would hand users a model that does not
carry over.

Writes experiments/results/saturating_in_auto.json.
Run: python experiments/saturating_in_auto.py   (~15 min on 2 cores: the default selection and the generalized PI fits)
"""

import json
import time
from pathlib import Path

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

import piest_jax as pj  # noqa: E402

HOLDOUT = 0.3
GRID = (16, 16)
GPI_PLAYS, GPI_TERMS = 8, 2


def _rmse(e) -> float:
    return float(np.sqrt(np.mean(np.square(e))))


def preisach_scores(rec, val, monotone: bool) -> dict:
    """The Preisach model's held-out RMSE on the record's last 30 % and, fitted on all of it,
    its RMSE on the record and (raw, from relaxed states) on the validation run."""
    T = len(rec.u)
    n_fit = int(round((1 - HOLDOUT) * T))
    mask = np.zeros(T)
    mask[:n_fit] = 1.0
    held = pj.fit_preisach(
        rec.u, rec.y, n_widths=GRID[0], n_centres=GRID[1], mask=mask, monotone=monotone, covariance=None
    )
    out = {"heldout_rmse": _rmse(np.asarray(held.model(rec.u))[n_fit:] - rec.y[n_fit:])}
    full = pj.fit_preisach(rec.u, rec.y, n_widths=GRID[0], n_centres=GRID[1], monotone=monotone, covariance=None)
    out["rmse"] = float(full.rmse)
    if val is not None:
        out["validation_rmse"] = _rmse(np.asarray(full.model(val.u)) - val.y)
    return out


def gpi_scores(rec, val) -> dict:
    """The same three numbers for the generalized PI (8 plays, 2 output terms: the B-H study's)."""
    T = len(rec.u)
    n_fit = int(round((1 - HOLDOUT) * T))
    mask = np.zeros(T)
    mask[:n_fit] = 1.0
    held = pj.fit_gpi(rec.u, rec.y, GPI_PLAYS, n_terms=GPI_TERMS, mask=mask, covariance=None)
    out = {"heldout_rmse": _rmse(np.asarray(held.model(rec.u))[n_fit:] - rec.y[n_fit:])}
    full = pj.fit_gpi(rec.u, rec.y, GPI_PLAYS, n_terms=GPI_TERMS, covariance=None)
    out["rmse"] = float(full.rmse)
    if val is not None:
        out["validation_rmse"] = _rmse(np.asarray(full.model(val.u)) - val.y)
    return out


def main():
    runs = {
        "aye2018": ("piezo_aye2018_identification", "piezo_aye2018_validation"),
        "chandra2023": ("piezo_chandra2023_1hz", None),
    }
    result = {"holdout": HOLDOUT, "grid": list(GRID), "records": {}}
    for label, (name, val_name) in runs.items():
        rec = pj.load_dataset(name)
        val = pj.load_dataset(val_name) if val_name else None
        t0 = time.time()
        ident = pj.identify(rec, val)
        sel = ident.selection
        default = {
            "structure": sel.structure,
            "n_plays": sel.n_plays,
            "n_lags": sel.n_lags,
            # The chosen candidate's score (a better one may have been rejected as undetermined).
            "heldout_rmse": float(dict(zip(sel.candidates, sel.scores))[(sel.n_plays, sel.n_lags)]),
            "rmse": float(ident.fit.rmse),
            "seconds": time.time() - t0,
        }
        if ident.validation is not None:
            default["validation_rmse"] = float(ident.validation.raw.rmse)
        entry = {"default_auto": default}
        for monotone in (True, False):
            t0 = time.time()
            entry["preisach_monotone" if monotone else "preisach_signed"] = dict(
                preisach_scores(rec, val, monotone), seconds=time.time() - t0
            )
        t0 = time.time()
        entry["gpi"] = dict(gpi_scores(rec, val), seconds=time.time() - t0)
        result["records"][label] = entry
        print(label, json.dumps(entry, indent=1), flush=True)
    out = Path(__file__).parent / "results" / "saturating_in_auto.json"
    out.write_text(json.dumps(result, indent=1) + "\n")
    print(out)


if __name__ == "__main__":
    main()
