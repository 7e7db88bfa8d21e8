"""`piest fit` and `piest diagnose` with their defaults on first-order reversal curves: fit on
every other curve, predict the curves in between, against a plain 20-play least-squares PI with
signed weights (`pj.uniform_pi`); and each interior loop of the shipped B-H files predicted from
the file's other loops. Writes experiments/results/reversal_curves.json.

The curves come from a generator of this script's own, not the project's model classes: a
relay (Preisach) model on a fine grid of switching fields, its density a log-normal in the
coercive field times a Gaussian in the interaction field, a reversible part, and a saturating
output. Each curve starts at positive saturation, comes down to its reversal field (not
recorded), then goes up to saturation again (recorded, one `segment` per curve), as a FORC
measurement does. The files carry the segment column, so the commands take the curves one after
another (`docs/data.md`).

    python experiments/reversal_curves.py            # ~10 min on 2 cores
    python experiments/reversal_curves.py --loops-only   # the shipped B-H loops alone, ~3 min
"""

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

import piest_jax as pj  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "experiments" / "results"

# Three materials: (coercive field median, its log-spread, interaction spread, reversible share,
# output saturation gain).
MATERIALS = {
    "soft": (0.12, 0.35, 0.06, 0.10, 1.0),
    "hard": (0.45, 0.30, 0.10, 0.05, 1.6),
    "spread": (0.25, 0.70, 0.15, 0.20, 1.3),
}


class Relays:
    """A relay model: relay (a, b) with a >= b switches up at u >= a and down at u <= b."""

    def __init__(self, hc0, spread, interaction, k=80, span=1.3):
        a = np.linspace(-span, span, k)
        self.up, self.down = np.meshgrid(a, a, indexing="ij")
        keep = self.up >= self.down
        hc, hi = (self.up - self.down) / 2, (self.up + self.down) / 2
        with np.errstate(divide="ignore"):
            log_hc = np.log(np.where(keep, np.maximum(hc, 1e-9), 1.0) / hc0)
        mu = np.exp(-(log_hc**2) / (2 * spread**2) - hi**2 / (2 * interaction**2)) * keep
        self.mu = mu / mu.sum()
        self.state = -np.ones_like(self.mu)
        self.keep = keep

    def run(self, u):
        out = np.empty(len(u))
        for i, v in enumerate(u):
            self.state[(self.up <= v) & self.keep] = 1.0
            self.state[(self.down >= v) & self.keep] = -1.0
            out[i] = np.sum(self.mu * self.state)
        return out


def curves(material, n_curves, step, noise, seed):
    """Rows (segment, H, B) of `n_curves` reversal curves, the reversal fields uniform in
    [-1, 1)."""
    hc0, spread, interaction, reversible, gain = MATERIALS[material]
    rng = np.random.default_rng(seed)
    relays = Relays(hc0, spread, interaction)
    relays.run(np.linspace(-1.0, 1.0, 200))  # the major loop's ascending branch, to saturation
    rows = []
    for i, hr in enumerate(np.linspace(-1.0, 1.0, n_curves, endpoint=False)):
        relays.run(np.arange(1.0, hr, -step))
        h = np.arange(hr, 1.0 + 1e-9, step)
        m = (1 - reversible) * relays.run(h) + reversible * np.tanh(3 * h)
        b = np.tanh(gain * m) / np.tanh(gain) + rng.normal(0.0, noise, len(h))
        rows += [(i, hh, bb) for hh, bb in zip(h, b)]
    return np.asarray(rows)


def write(path, rows):
    np.savetxt(path, rows, delimiter=",", header="segment,H,B", comments="", fmt=["%d", "%.7f", "%.7f"])


def command(name, train, val, out):
    """`piest <name>` with its defaults on the training file, validated on the other:
    (its JSON report, seconds). A command that fails stops the study."""
    t0 = time.time()
    argv = [name, str(train), "--columns", "H,B", "--validate", str(val), "--out", str(out), "--quiet"]
    if pj.run_cli(argv) != 0:
        raise SystemExit(f"piest {name} failed on {train}")
    report = out / ("fit.json" if name == "fit" else "report.json")
    return json.loads(report.read_text()), time.time() - t0


def baseline(train, val):
    """The plain 20-play least-squares PI (signed weights) fitted on the training curves joined,
    run on the validation curves joined from rest at their first input."""
    fit = pj.uniform_pi(train[:, 1], train[:, 2], 20)
    op = pj.PIOperator(fit.thresholds, fit.weights, initial_states=val[0, 1])
    pred = np.asarray(op(val[:, 1])) + float(fit.offset)
    return float(np.sqrt(np.mean((pred - val[:, 2]) ** 2)))


def one(material, n_curves, step, noise, seed, work):
    rows = curves(material, n_curves, step, noise, seed)
    train, val = rows[rows[:, 0] % 2 == 0], rows[rows[:, 0] % 2 == 1]
    tr, va = work / f"{material}_train.csv", work / f"{material}_val.csv"
    write(tr, train)
    write(va, val)
    base = baseline(train, val)
    res = {"samples": len(rows), "train_samples": len(train), "curves": n_curves, "baseline_rmse": base}
    fit, seconds = command("fit", tr, va, work / f"{material}_fit")
    res["fit"] = {
        "seconds": seconds,
        "structure": fit["structure"],
        "n_plays": fit.get("n_plays"),
        "validation_rmse": fit["validation_rmse"],
        "ratio": fit["validation_rmse"] / base,
        "segments_joined": fit.get("segments_joined"),
    }
    rep, seconds = command("diagnose", tr, va, work / f"{material}_diagnose")
    res["diagnose"] = {
        "seconds": seconds,
        "effects": rep["effects"],
        "validation_baseline_rmse": rep["validation"]["baseline_rmse"],
        "validation_final_rmse": rep["validation"]["final_rmse"],
        "ratio": rep["validation"]["final_rmse"] / base,
    }
    return res


def shipped_loops(work):
    """The shipped B-H loop files: each interior loop predicted from the others (the other loops
    joined in the file's order), by `piest fit` and `piest diagnose` with their defaults and by
    the 20-play PI."""
    res = {}
    for name in ("bh_szewczyk2016_M130_27s", "bh_szewczyk2016_MnZn_HP_ferrite", "bh_szewczyk2016_MnZn_ferrite"):
        rec = pj.load_dataset(name, columns="H,B")
        rows = np.column_stack([rec.segment, rec.u, rec.y])
        labels = [s.segment[0] for s in rec.segments()]
        for label in labels[1:-1]:
            train, val = rows[rows[:, 0] != label], rows[rows[:, 0] == label]
            tr, va = work / f"{name}_{label:g}_train.csv", work / f"{name}_{label:g}_val.csv"
            write(tr, train)
            write(va, val)
            entry = {"loop": float(label), "baseline_rmse": baseline(train, val)}
            fit, seconds = command("fit", tr, va, work / f"{name}_{label:g}_fit")
            entry["fit"] = {
                "structure": fit["structure"],
                "n_plays": fit.get("n_plays"),
                "rmse": fit["validation_rmse"],
                "seconds": seconds,
            }
            rep, seconds = command("diagnose", tr, va, work / f"{name}_{label:g}_diagnose")
            entry["diagnose"] = {"effects": rep["effects"], "rmse": rep["validation"]["final_rmse"], "seconds": seconds}
            for c in ("fit", "diagnose"):
                entry[c]["ratio"] = entry[c]["rmse"] / entry["baseline_rmse"]
            res[f"{name} loop {label:g}"] = entry
            print(
                f"{name} loop {label:g}: PI 20 plays {entry['baseline_rmse']:.4f}; fit {entry['fit']['structure']} "
                f"{entry['fit']['rmse']:.4f} ({entry['fit']['ratio']:.2f}x); diagnose {entry['diagnose']['effects']} "
                f"{entry['diagnose']['rmse']:.4f} ({entry['diagnose']['ratio']:.2f}x)",
                flush=True,
            )
    return res


def main_():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--curves", type=int, default=120)
    ap.add_argument("--step", type=float, default=0.008)
    ap.add_argument("--noise", type=float, default=0.002)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=str(RESULTS / "reversal_curves.json"))
    ap.add_argument(
        "--loops-only",
        action="store_true",
        help="rerun only the shipped B-H loops, keeping the reversal curves' results already in --out",
    )
    args = ap.parse_args()
    loops_only = args.loops_only
    del args.loops_only
    res = {"settings": vars(args).copy(), "materials": {}}
    if loops_only:
        res = json.loads(Path(args.out).read_text())
    with tempfile.TemporaryDirectory() as tmp:
        for i, name in enumerate([] if loops_only else MATERIALS):
            r = one(name, args.curves, args.step, args.noise, args.seed + i, Path(tmp))
            res["materials"][name] = r
            print(
                f"{name}: {r['samples']} samples; PI 20 plays {r['baseline_rmse']:.4f}; "
                f"fit {r['fit']['structure']} {r['fit']['validation_rmse']:.4f} ({r['fit']['ratio']:.2f}x, "
                f"{r['fit']['seconds']:.0f} s); diagnose {r['diagnose']['effects']} "
                f"{r['diagnose']['validation_final_rmse']:.4f} ({r['diagnose']['ratio']:.2f}x, "
                f"{r['diagnose']['seconds']:.0f} s)",
                flush=True,
            )
        res["shipped_bh_loops"] = shipped_loops(Path(tmp))
    if not loops_only:
        res["settings"]["out"] = os.path.relpath(res["settings"]["out"], ROOT)
    Path(args.out).write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    main_()
