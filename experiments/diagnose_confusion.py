"""Confusion matrix of `piest diagnose` over records from the hidden-effect generator.

Writes experiments/results/confusion.json and prints a markdown table. Each row is the hidden
effect (or pair); each column what the diagnosis named first (or "none"); two-effect rows count a
record as right when both names are found.

    python experiments/diagnose_confusion.py --per-class 30 --samples 2000
"""

import argparse
import json
import time
from collections import Counter
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

from piest_jax import _diagnose, _effects, _hidden  # noqa: E402

PAIRS = [("delay", "asymmetry"), ("linear_dynamics", "offset_drift"), ("creep", "asymmetry"),
         ("initial_state", "rate_dependence")]


def run(per_class, n_samples, seed, pairs_per_class):
    key = jax.random.PRNGKey(seed)
    classes = [()] + [(e,) for e in _effects.EFFECTS] + PAIRS
    rows = []
    t0 = time.time()
    for ci, cls in enumerate(classes):
        n = pairs_per_class if len(cls) == 2 else per_class
        for i in range(n):
            k = jax.random.fold_in(jax.random.fold_in(key, ci), i)
            rec, truth = _hidden.generate(cls, key=k, n_samples=n_samples)
            s = _diagnose.search(rec)
            _, rmse = _diagnose.evaluate(rec, s["scaling"], s["theta_final"], s["effects"])
            rows.append(dict(hidden=list(cls), named=s["effects"], forms=truth["forms"],
                             noise_std=truth["noise_std"], final_rmse=rmse,
                             noise_est=s["noise_std"]))
            print(cls, truth["forms"], "->", s["effects"], f"rmse/noise={rmse / truth['noise_std']:.2f}", flush=True)
    return rows, time.time() - t0


def summarise(rows):
    table = {}
    for r in rows:
        h = "+".join(r["hidden"]) or "none"
        got = "+".join(r["named"]) or "none"
        table.setdefault(h, Counter())[got] += 1
    stats = {}
    for h, c in table.items():
        hidden = [] if h == "none" else h.split("+")
        sel = [r for r in rows if "+".join(r["hidden"]) == ("" if h == "none" else h)]
        right = [r for r in sel if set(r["named"]) == set(hidden)]
        stats[h] = dict(n=len(sel), right=len(right), share=len(right) / len(sel),
                        rmse_ok=sum(r["final_rmse"] <= 1.5 * r["noise_std"] for r in right),
                        named=dict(c))
    return stats


def markdown(stats):
    cols = ["none", *_effects.EFFECTS]
    lines = ["| hidden \\ named first | " + " | ".join(cols) + " | right | RMSE ≤ 1.5σ when right |",
             "|---" * (len(cols) + 3) + "|"]
    for h, s in stats.items():
        firsts = Counter()
        for got, k in s["named"].items():
            firsts[got.split("+")[0]] += k
        cells = [str(firsts.get(c, 0)) for c in cols]
        lines.append(f"| {h} | " + " | ".join(cells) + f" | {s['right']}/{s['n']} | {s['rmse_ok']}/{s['right']} |")
    return "\n".join(lines)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--per-class", type=int, default=30)
    ap.add_argument("--pairs", type=int, default=10)
    ap.add_argument("--samples", type=int, default=2000)
    ap.add_argument("--seed", type=int, default=2024)
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "confusion.json"))
    a = ap.parse_args()
    rows, secs = run(a.per_class, a.samples, a.seed, a.pairs)
    stats = summarise(rows)
    md = markdown(stats)
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(dict(per_class=a.per_class, samples=a.samples, seed=a.seed,
                                           seconds=secs, stats=stats, rows=rows, table=md), indent=1))
    Path(a.out).with_suffix(".md").write_text(md + "\n")
    print(md)
    print(f"{len(rows)} records in {secs:.0f} s")


if __name__ == "__main__":
    main()
