"""The exact excitation condition against exact arithmetic, on fresh Monte Carlo draws.

    python experiments/exact_condition_study.py [--draws 3000] [--seed 2026] [--check 60]
        ->  experiments/results/exact_condition_study.json
    python experiments/exact_condition_study.py --families all --draws 50000 --samples 2000 \
        --window 400 --seed 100 --check 40 --out part0.json      (and --start 50000 --out part1.json)
    python experiments/exact_condition_study.py --merge part0.json part1.json --out all.json

Runs a settled map (`pj.pe_map(..., settle=True)`): every draw whose event level
(`pj.exact_condition`, Theorem 2 of docs/excitation_condition.md) is below `pj.settle_band` or
whose two float verdicts (event level, raw Gram λ_min/λ_max > 2.2e-12) disagree is decided by the
rank of its play outputs in exact arithmetic (`pj.exact_draw_pe`). The map's `exact_condition`
violations then count the draws above the band whose float verdict exact arithmetic contradicts.
As an independent check, `--check` draws the map did not settle are decided by `tests/reference.py`'s
`exact_window_pe` (exact rational arithmetic, Fraction elimination) and counted against both float
verdicts. The report also says how often settling overturned each float verdict, and how far the
float event levels of the truly deficient and the truly full-rank settled draws sit from the band.
"""

import argparse
import json
import sys
import time
from pathlib import Path

import jax
import numpy as np

import piest_jax as pj

jax.config.update("jax_enable_x64", True)
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from reference import exact_window_pe as rational_window_pe  # noqa: E402  (the tests' reference)

OUT = Path(__file__).parent / "results" / "exact_condition_study.json"
SUMMED = ("draws", "settled", "pe", "exact_condition_holds", "checked", "seconds", "settle_seconds", "check_seconds")


def draw(settings, key, i):
    k = pj.draw_keys(key, i, 1)[0]
    family = int(pj.draw_family(i, settings))
    case = jax.jit(pj.draw_case, static_argnums=(1, 3))(k, family, settings.times(), settings.n_plays)
    return [np.asarray(a) for a in case]


def study(args) -> dict:
    chosen = (
        {}
        if args.families == "default"
        else {"families": pj.INPUT_FAMILIES if args.families == "all" else tuple(args.families.split(","))}
    )
    s = pj.make_settings(n_samples=args.samples, window=args.window, dtype="float64", **chosen)
    key = jax.random.key(args.seed)
    res = pj.pe_map(key, args.draws, s, start=args.start, settle=True, quiet=True)
    summary = pj.summarise(res)
    tol, band = pj.numerical_tolerance("float64"), pj.settle_band(s.n_samples, s.n_plays, s.dtype)
    raw_pe = res.c1_normalised > tol
    float_exact = res.exact_level > tol
    settled, pe = res.settled, res.pe
    rows = []
    overturned = np.flatnonzero(settled & ((float_exact != pe) | (raw_pe != pe)))
    for i in overturned:
        rows.append(
            dict(
                draw=args.start + int(i),
                family=pj.INPUT_FAMILIES[int(res.family[i])],
                pe=bool(pe[i]),
                float_exact_condition=bool(float_exact[i]),
                raw_gram_pe=bool(raw_pe[i]),
                event_level=float(res.exact_level[i]),
                raw_level=float(res.c1_normalised[i]),
            )
        )
    rng = np.random.default_rng(args.seed + args.start)
    unsettled = np.flatnonzero(~settled)
    checks = np.sort(rng.choice(unsettled, min(args.check, unsettled.size), replace=False))
    t0 = time.perf_counter()
    check_rows = []
    for i in checks:
        u, r, x0, _ = draw(s, key, args.start + int(i))
        truth = bool(np.all(rational_window_pe(u, r, x0, s.window, s.stride)))
        check_rows.append(
            dict(
                draw=args.start + int(i),
                pe_exact_rational=truth,
                map_pe=bool(pe[i]),
                map_exact_condition=bool(res.exact[i]),
            )
        )
    deficient = res.exact_level[settled & ~pe]
    full = res.exact_level[settled & pe]
    return dict(
        seed=args.seed,
        start=args.start,
        draws=args.draws,
        settings=s._asdict(),
        tolerance=tol,
        band=band,
        settled=int(settled.sum()),
        pe=int(pe.sum()),
        exact_condition_holds=int(res.exact.sum()),
        exact_condition_mismatches=dict(
            holds_but_not_pe=summary["sharper_holds_not_pe"], fails_but_pe=summary["sharper_fails_pe"]
        ),
        float_exact_condition_overturned=int((settled & (float_exact != pe)).sum()),
        raw_gram_overturned=int((settled & (raw_pe != pe)).sum()),
        largest_event_level_not_pe=float(deficient.max()) if deficient.size else None,
        smallest_event_level_settled_pe=float(full.min()) if full.size else None,
        checked=len(check_rows),
        check_mismatches=sum(
            r["pe_exact_rational"] != r["map_pe"] or r["pe_exact_rational"] != r["map_exact_condition"]
            for r in check_rows
        ),
        seconds=float(res.seconds),
        settle_seconds=float(res.settle_seconds),
        check_seconds=time.perf_counter() - t0,
        per_family={
            f: dict(
                draws=int((res.family == j).sum()),
                settled=int((settled & (res.family == j)).sum()),
                pe=int((pe & (res.family == j)).sum()),
            )
            for j, f in enumerate(pj.INPUT_FAMILIES)
            if j in s.families
        },
        overturned=rows,
        checks=check_rows,
    )


def merge(paths) -> dict:
    """One report from the parts of a study run in pieces (`--start`)."""
    parts = sorted((json.loads(Path(p).read_text()) for p in paths), key=lambda d: d["start"])
    first = parts[0]
    for a, b in zip(parts, parts[1:]):
        if a["start"] + a["draws"] != b["start"] or a["seed"] != b["seed"] or a["settings"] != b["settings"]:
            raise SystemExit("the parts must be consecutive draws of one seed and settings")
    out = {k: first[k] for k in ("seed", "start", "settings", "tolerance", "band")}
    out |= {k: sum(p[k] for p in parts) for k in SUMMED}
    out |= {
        k: sum(p[k] for p in parts)
        for k in ("float_exact_condition_overturned", "raw_gram_overturned", "check_mismatches")
    }
    out["exact_condition_mismatches"] = {
        k: sum(p["exact_condition_mismatches"][k] for p in parts) for k in first["exact_condition_mismatches"]
    }
    levels = [p["largest_event_level_not_pe"] for p in parts if p["largest_event_level_not_pe"] is not None]
    out["largest_event_level_not_pe"] = max(levels) if levels else None
    levels = [p["smallest_event_level_settled_pe"] for p in parts if p["smallest_event_level_settled_pe"] is not None]
    out["smallest_event_level_settled_pe"] = min(levels) if levels else None
    out["per_family"] = {
        f: {k: sum(p["per_family"][f][k] for p in parts) for k in v} for f, v in first["per_family"].items()
    }
    out["parts"] = [str(p) for p in paths]
    out["overturned"] = [r for p in parts for r in p["overturned"]]
    out["checks"] = [r for p in parts for r in p["checks"]]
    return out


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--draws", type=int, default=3000)
    p.add_argument("--seed", type=int, default=2026)
    p.add_argument("--check", type=int, default=60, help="unsettled draws checked in rational arithmetic")
    p.add_argument("--samples", type=int, default=5000)
    p.add_argument("--window", type=int, help="default samples // 5")
    p.add_argument("--families", default="default", help="`default`, `all` or comma-separated names")
    p.add_argument("--start", type=int, default=0, help="first draw number (a long study in parts)")
    p.add_argument("--merge", nargs="+", metavar="PART", help="merge part reports instead of running")
    p.add_argument("--out", default=str(OUT))
    args = p.parse_args(argv)
    report = merge(args.merge) if args.merge else study(args)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(report, indent=1))
    print(json.dumps({k: v for k, v in report.items() if k not in ("overturned", "checks", "settings", "per_family")}))
    print(args.out)


if __name__ == "__main__":
    main()
