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
(`preisach_bh.py`). Then whether a coarser grid is the remedy: the finest of 16, 12, 10, 8, 6
and 4 squared that leaves no parameter undetermined, against 16 x 16, on the Aye validation run,
the B–H held-out loops, and a synthetic Preisach plant (a smooth density off a PI's line)
fitted on one repeated loop or on random reversals of every size and run on other reversals.

Writes experiments/results/preisach_determined.json.
Run: python experiments/preisach_determined.py   (~1.5 min on 2 cores)
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


GRIDS = (16, 12, 10, 8, 6, 4)


def determined_grid(u, y, **kwargs):
    """The 16 x 16 monotone fit, and the finest square grid's whose fit leaves no parameter
    undetermined (else the coarsest): (16 x 16 fit, that fit, [(size, undetermined parameters)
    for each grid fitted])."""
    fits, tried = [], []
    for g in GRIDS:
        fits.append(pj.fit_preisach(u, y, n_widths=g, n_centres=g, monotone=True, **kwargs))
        tried.append((g, int(np.sum(np.asarray(fits[-1].undetermined)))))
        if tried[-1][1] == 0:
            break
    return fits[0], fits[-1], tried


def _rmse(e) -> float:
    return float(np.sqrt(np.mean(np.square(e))))


def synthetic_plant():
    """A 12 x 12 Preisach model with a smooth bump of density off the line a PI's weights lie on."""
    r = np.linspace(0.0, 1.0, 12, endpoint=False)
    c = np.linspace(-1.0, 1.0, 12)
    R, C = np.meshgrid(r, c, indexing="ij")
    mu = np.exp(-(C**2) / 0.1 - (R - 0.2) ** 2 / 0.05) * (np.abs(C) < 1 - R)
    return pj.Preisach(r, c, mu / mu.sum())


def reversals(seed, turns=50, T=1500):
    """An input through random reversal points of every size in [-1, 1], linear between them."""
    rng = np.random.default_rng(seed)
    points = [0.0]
    for _ in range(turns):
        points.append(float(np.clip(points[-1] + rng.choice([-1, 1]) * rng.uniform(0.1, 1.8), -1, 1)))
    return np.interp(np.linspace(0, turns, T), np.arange(turns + 1), points)


def coarser_grids() -> list:
    """The determined grid against 16 x 16 where the prediction can be checked."""
    rows = []
    rec, val = pj.load_dataset(PIEZO[0]), pj.load_dataset(PIEZO[1])
    f16, f, tried = determined_grid(rec.u, rec.y)
    rows.append(
        {
            "case": "Aye identification -> validation (raw)",
            "tried": tried,
            "rmse_determined": _rmse(np.asarray(f.model(val.u)) - val.y),
            "rmse_16": _rmse(np.asarray(f16.model(val.u)) - val.y),
        }
    )
    for name in [n for n in pj.datasets() if n.startswith("bh_")]:
        all_loops = loops(name)
        for held in range(1, len(all_loops) - 1):
            u, y, mask = twice([lp for k, lp in enumerate(all_loops) if k != held])
            h, b = all_loops[held]
            v = np.concatenate([h, h])
            f16, f, tried = determined_grid(u, y, mask=mask, initial_states=0.0)
            rows.append(
                {
                    "case": f"{name} held-out loop {held}",
                    "tried": tried,
                    "rmse_determined": _rmse(np.asarray(f.model(v))[len(h) :] - b),
                    "rmse_16": _rmse(np.asarray(f16.model(v))[len(h) :] - b),
                }
            )
    plant, u2 = synthetic_plant(), reversals(1)
    y2 = np.asarray(plant(u2))
    for label, u in (
        ("one repeated loop", np.sin(2 * np.pi * 10 * np.arange(1500) / 1500)),
        ("reversals", reversals(0)),
    ):
        y = np.asarray(plant(u)) + 0.003 * np.random.default_rng(0).standard_normal(u.size)
        f16, f, tried = determined_grid(u, y)
        rows.append(
            {
                "case": f"synthetic Preisach plant, fitted on {label}, run on other reversals",
                "tried": tried,
                "rmse_determined": _rmse(np.asarray(f.model(u2)) - y2),
                "rmse_16": _rmse(np.asarray(f16.model(u2)) - y2),
            }
        )
    for row in rows:
        print(json.dumps(row), flush=True)
    return rows


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
    coarser = coarser_grids()
    result = {"grid": list(GRID), "rows": rows, "aye_monotone_validation": aye, "coarser_grids": coarser}
    out.write_text(json.dumps(result, indent=1) + "\n")
    print(out)


if __name__ == "__main__":
    main()
