"""Confusion matrix of `piest diagnose` over records from the hidden-effect generator.

Writes experiments/results/diagnose_confusion.json (rewritten after every record, so a stopped
run keeps what it finished) and prints a markdown table. Each row is the hidden effect (or pair);
each column what the diagnosis named first (or "none"); a record counts as right when the set of
names equals the hidden set. The search runs with every registered effect as a candidate; the
final RMSE is that of the chosen model (fitted on the whole record) over the whole record, against
the true noise std. Each class's records come from `pj.hidden_effect_key` (the class's names).
`--shard i/k` runs every k-th record, for k processes; `--merge` combines their files.

    python experiments/diagnose_confusion.py --per-class 4 --pairs 2 --samples 500

`--noise-ar PHI` colours the sensor noise (AR(1), lag-one autocorrelation PHI, same std).
"""

import argparse
import json
import time
from collections import Counter
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import piest_jax as pj  # noqa: E402

PAIRS = [
    ("delay", "asymmetry"),
    ("linear_dynamics", "offset_drift"),
    ("creep", "asymmetry"),
    ("initial_state", "rate_dependence"),
    ("rate_dependence", "offset_drift"),
    ("linear_dynamics", "minor_loop_noncongruence"),
    ("minor_loop_noncongruence", "creep"),
    ("asymmetry", "saturation"),
    ("saturation", "creep"),
]


def jobs(per_class, pairs_per_class):
    classes = [()] + [(e,) for e in pj.EFFECTS] + PAIRS
    out = []
    # Interleaved by record index so that a run stopped early still covers every class.
    for i in range(max(per_class, pairs_per_class)):
        for cls in classes:
            if i < (pairs_per_class if len(cls) == 2 else per_class):
                out.append((i, cls))
    return out


def run(args, shard, n_shards, save):
    key = jax.random.PRNGKey(args.seed)
    rows = []
    t0 = time.time()
    for j, (i, cls) in enumerate(jobs(args.per_class, args.pairs)):
        if j % n_shards != shard:
            continue
        k = pj.hidden_effect_key(key, cls, i)
        rec, truth = pj.hidden_effect_record(cls, key=k, n_samples=args.samples, noise_ar=args.noise_ar)
        t1 = time.time()
        # The whole diagnosis: its search names the effects, and it reports both models' RMSE over
        # the whole record.
        d = pj.diagnose(rec)
        rmse, rmse0 = d.final_rmse, d.baseline_rmse
        rows.append(
            dict(
                hidden=list(cls),
                named=d.effects,
                pruned=d.pruned,
                forms=truth["forms"],
                noise_std=truth["noise_std"],
                baseline_rmse=rmse0,
                final_rmse=rmse,
                noise_est=d.noise_std_estimate,
                seconds=time.time() - t1,
            )
        )
        print(
            cls,
            truth["forms"],
            "->",
            d.effects,
            f"rmse/noise={rmse / truth['noise_std']:.2f}",
            f"{time.time() - t1:.0f}s",
            flush=True,
        )
        save(rows, time.time() - t0)
    return rows


def summarise(rows):
    table = {}
    for r in rows:
        h = "+".join(r["hidden"]) or "none"
        got = "+".join(r["named"]) or "none"
        table.setdefault(h, Counter())[got] += 1
    # Rows in the order of the classes (merged shards interleave them).
    order = ["none", *pj.EFFECTS, *("+".join(p) for p in PAIRS)]
    stats = {}
    for h, c in sorted(table.items(), key=lambda kv: order.index(kv[0]) if kv[0] in order else len(order)):
        hidden = [] if h == "none" else h.split("+")
        sel = [r for r in rows if "+".join(r["hidden"]) == ("" if h == "none" else h)]
        right = [r for r in sel if set(r["named"]) == set(hidden)]
        stats[h] = dict(
            n=len(sel),
            right=len(right),
            share=len(right) / len(sel),
            rmse_ok=sum(r["final_rmse"] <= 1.5 * r["noise_std"] for r in right),
            named=dict(c),
        )
    return stats


def totals(rows):
    """Shares named right for effect-free, single-effect and two-effect records."""
    out = {}
    for label, k in (("no_effect", 0), ("single", 1), ("pair", 2)):
        sel = [r for r in rows if len(r["hidden"]) == k]
        right = [r for r in sel if set(r["named"]) == set(r["hidden"])]
        out[label] = dict(
            n=len(sel),
            right=len(right),
            rmse_within_1_5_noise=sum(r["final_rmse"] <= 1.5 * r["noise_std"] for r in right),
        )
    return out


def markdown(stats):
    cols = ["none", *pj.EFFECTS]
    lines = [
        "| hidden \\ named first | " + " | ".join(cols) + " | right | RMSE ≤ 1.5σ when right |",
        "|---" * (len(cols) + 3) + "|",
    ]
    for h, s in stats.items():
        firsts = Counter()
        for got, k in s["named"].items():
            firsts[got.split("+")[0]] += k
        cells = [str(firsts.get(c, 0)) for c in cols]
        lines.append(f"| {h} | " + " | ".join(cells) + f" | {s['right']}/{s['n']} | {s['rmse_ok']}/{s['right']} |")
    return "\n".join(lines)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--per-class", type=int, default=4)
    ap.add_argument("--pairs", type=int, default=2)
    ap.add_argument("--samples", type=int, default=500)
    ap.add_argument("--seed", type=int, default=2024)
    ap.add_argument(
        "--noise-ar", type=float, default=0.0, help="lag-one autocorrelation of the sensor noise (AR(1); 0 is white)"
    )
    ap.add_argument("--shard", default="0/1", help="i/k: run every k-th record starting at i")
    ap.add_argument("--merge", nargs="*", help="combine these shard files into --out and stop")
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "diagnose_confusion.json"))
    a = ap.parse_args()
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)

    meta = dict(per_class=a.per_class, pairs=a.pairs, samples=a.samples, seed=a.seed, noise_ar=a.noise_ar)

    def save(rows, secs, settings=meta):
        stats = summarise(rows)
        md = markdown(stats)
        out.write_text(
            json.dumps(
                dict(
                    **settings, seconds=secs, n_records=len(rows), totals=totals(rows), stats=stats, rows=rows, table=md
                ),
                indent=1,
            )
        )
        return md

    if a.merge is not None:
        parts = [json.loads(Path(p).read_text()) for p in a.merge]
        # The study's settings are the shards' (this command's own options do not apply).
        metas = [{k: p[k] for k in meta} for p in parts]
        if any(m != metas[0] for m in metas):
            ap.error(f"the shards were run with different settings: {metas}")
        rows = [r for p in parts for r in p["rows"]]
        md = save(rows, sum(p["seconds"] for p in parts), metas[0])
    else:
        i, k = (int(x) for x in a.shard.split("/"))
        rows = run(a, i, k, save)
        md = save(rows, sum(r["seconds"] for r in rows))
    print(md)
    print(f"{len(rows)} records")


if __name__ == "__main__":
    main()
