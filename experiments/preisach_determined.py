"""Which records determine a Preisach density? Undetermined cells on the piezo runs and the B–H loops.

`--model auto` never keeps a candidate with a parameter the record does not determine (fit.json's
`undetermined`). A Preisach fit reports the same thing for its cells (`PreisachFit.undetermined`:
a cell whose relays switch only together with others is set by the smoothness penalty, not by
the data). This script counts them, 16 x 16 grid, density >= 0 and signed, on
- the Aye piezo identification and validation runs and the Chandra record (whole records), and
- the training records of the B–H study (`preisach_bh.py`: every loop of a file but one, each
  played twice, the first pass masked, plays starting at 0),
and where the monotone model fitted on the Aye identification run errs on the validation run,
to see whether that rule alone would keep the Preisach model off the records where it does not
carry over (`saturating_in_auto.py`) and let it in where it predicts held-out loops well
(`preisach_bh.py`).

Writes experiments/results/preisach_determined.json.
Run: python experiments/preisach_determined.py   (~1 min on 2 cores)
"""

import json
from pathlib import Path

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

from preisach_bh import GRID, loops, twice  # noqa: E402

import piest_jax as pj  # noqa: E402

PIEZO = ("piezo_aye2018_identification", "piezo_aye2018_validation", "piezo_chandra2023_1hz")


def counts(u, y, **kwargs) -> dict:
    """Cells of the triangle, undetermined cells and effective parameters, for both densities."""
    out = {}
    for monotone in (True, False):
        f = pj.fit_preisach(u, y, n_widths=GRID[0], n_centres=GRID[1], monotone=monotone, **kwargs)
        undetermined = np.asarray(f.undetermined)[:-1]  # the last parameter is the offset
        out["monotone" if monotone else "signed"] = {
            "cells": int(undetermined.size),
            "undetermined_cells": int(undetermined.sum()),
            "effective_parameters": float(f.effective_parameters),
        }
    return out


def aye_validation() -> dict:
    """The monotone Preisach model fitted on the Aye identification run, run on the validation
    run: raw RMSE, RMSE with the mean removed, and per tenth of the run the mean residual and
    the input's range (where the error sits)."""
    rec, val = pj.load_dataset(PIEZO[0]), pj.load_dataset(PIEZO[1])
    f = pj.fit_preisach(rec.u, rec.y, n_widths=GRID[0], n_centres=GRID[1], monotone=True, covariance=None)
    u = np.asarray(val.u)
    e = np.asarray(f.model(u)) - np.asarray(val.y)
    tenths = np.array_split(np.arange(len(e)), 10)
    return {
        "validation_rmse": float(np.sqrt(np.mean(e**2))),
        "validation_rmse_mean_removed": float(np.std(e)),
        "by_tenth": [
            {"mean_residual": float(e[i].mean()), "input_min": float(u[i].min()), "input_max": float(u[i].max())}
            for i in tenths
        ],
    }


def main():
    rows = []
    for name in PIEZO:
        rec = pj.load_dataset(name)
        rows.append({"record": name, "samples": len(rec.u), **counts(rec.u, rec.y)})
        print(json.dumps(rows[-1]), flush=True)
    for name in [n for n in pj.datasets() if n.startswith("bh_")]:
        all_loops = loops(name)
        for held in range(1, len(all_loops) - 1):
            u, y, mask = twice([lp for k, lp in enumerate(all_loops) if k != held])
            row = {"record": name, "held_out_loop": held, "samples": int(mask.sum())}
            rows.append({**row, **counts(u, y, mask=mask, initial_states=0.0)})
            print(json.dumps(rows[-1]), flush=True)
    out = Path(__file__).parent / "results" / "preisach_determined.json"
    aye = aye_validation()
    print(json.dumps(aye), flush=True)
    out.write_text(json.dumps({"grid": list(GRID), "rows": rows, "aye_monotone_validation": aye}, indent=1) + "\n")
    print(out)


if __name__ == "__main__":
    main()
