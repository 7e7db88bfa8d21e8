"""The exact excitation condition against exact arithmetic, on fresh Monte Carlo draws.

    python experiments/exact_condition_study.py [--draws 3000] [--seed 2026] [--check 60]
        ->  experiments/results/exact_condition_study.json
    python experiments/exact_condition_study.py --settle-all --families all --draws 10000 \
        --samples 2000 --window 400 --seed 100 --out experiments/results/exact_condition_settled.json

Runs a map (T = 5000, n = 10 plays, windows of 1000 samples every 100, the seven default families,
float64), then settles, in exact rational arithmetic, every draw where the exact condition
(`pj.exact_condition`, Theorem 2 of docs/excitation_condition.md) and the numerical verdict on the
raw Gram (λ_min/λ_max > 2.2e-12) disagree, plus `--check` draws drawn at random among those where
they agree (half of them where both say "not PE", where a float decision could be wrong). The
reference is `tests/reference.py`'s `exact_window_pe`: the play outputs of the sampled input
computed without rounding (every float is a dyadic rational) and their rank per window by
integer elimination. The condition's mismatches are counted against that reference.
"""

import argparse
import json
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import piest_jax as pj

jax.config.update("jax_enable_x64", True)
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from reference import exact_window_pe as rational_window_pe  # noqa: E402  (the tests' reference)

OUT = Path(__file__).parent / "results" / "exact_condition_study.json"


def draw(settings, key, i):
    t = jnp.arange(settings.n_samples) * settings.dt
    k = pj.draw_keys(key, i, 1)[0]
    family = int(pj.draw_family(i, settings))
    case = jax.jit(pj.draw_case, static_argnums=(1, 3))(k, family, t, settings.n_plays)
    return [np.asarray(a) for a in case]


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--draws", type=int, default=3000)
    p.add_argument("--seed", type=int, default=2026)
    p.add_argument("--check", type=int, default=60, help="agreeing draws checked at random")
    p.add_argument("--samples", type=int, default=5000)
    p.add_argument("--window", type=int, help="default samples // 5")
    p.add_argument("--families", default="default", help="`default`, `all` or comma-separated names")
    p.add_argument("--start", type=int, default=0, help="first draw number (a long study in parts)")
    p.add_argument("--settle-all", action="store_true", help="settle every 'not PE' draw exactly")
    p.add_argument("--out", default=str(OUT))
    args = p.parse_args(argv)
    chosen = {} if args.families == "default" else {
        "families": pj.INPUT_FAMILIES if args.families == "all" else tuple(args.families.split(","))}
    s = pj.make_settings(n_samples=args.samples, window=args.window, dtype="float64", **chosen)
    key = jax.random.key(args.seed)
    res = pj.pe_map(key, args.draws, s, start=args.start, quiet=True)
    tol = pj.numerical_tolerance("float64")
    pe, exact = res["c1_normalised"] > tol, res["exact"]
    disputed = np.flatnonzero(pe != exact)
    rng = np.random.default_rng(args.seed)
    agree_no = np.flatnonzero(~pe & ~exact)
    agree_yes = np.flatnonzero(pe & exact)
    half = args.check // 2
    sample = np.concatenate([rng.choice(agree_no, min(half, agree_no.size), replace=False),
                             rng.choice(agree_yes, min(args.check - half, agree_yes.size), replace=False)])
    rows, t0 = [], time.perf_counter()
    todo = np.concatenate([disputed, np.sort(sample)])
    if args.settle_all:
        todo = np.unique(np.concatenate([todo, np.flatnonzero(~exact)]))
    for i in todo:
        u, r, x0, _ = draw(s, key, args.start + int(i))
        truth = bool(np.all(pj.exact_window_pe(u, r, x0, s.window, stride=s.stride) if args.settle_all
                            else rational_window_pe(u, r, x0, s.window, s.stride)))
        rows.append(dict(draw=args.start + int(i), family=pj.INPUT_FAMILIES[int(res["family"][i])],
                         raw_gram_pe=bool(pe[i]),
                         exact_condition=bool(exact[i]), exact_arithmetic_pe=truth,
                         raw_level=float(res["c1_normalised"][i]), event_level=float(res["exact_level"][i])))
    kept = set(disputed.tolist()) | set(sample.tolist())
    # A long settled study keeps the rows worth reading: the disputes, the random checks and any
    # draw that either float verdict got wrong; the rest are counted.
    shown = [r for r in rows if r["draw"] - args.start in kept or r["exact_condition"] != r["exact_arithmetic_pe"]
             or r["raw_gram_pe"] != r["exact_arithmetic_pe"]]
    report = dict(
        seed=args.seed, start=args.start, draws=args.draws, settings=s._asdict(), tolerance=tol,
        pe_raw_gram=int(pe.sum()), exact_condition_holds=int(exact.sum()),
        disputed=int(disputed.size), checked=len(rows),
        exact_condition_mismatches=dict(
            holds_but_not_pe=sum(r["exact_condition"] and not r["exact_arithmetic_pe"] for r in rows),
            fails_but_pe=sum(not r["exact_condition"] and r["exact_arithmetic_pe"] for r in rows),
        ),
        raw_gram_mismatches=sum(r["raw_gram_pe"] != r["exact_arithmetic_pe"] for r in rows),
        exact_arithmetic_seconds=time.perf_counter() - t0,
        map_seconds=float(res["seconds"]),
        rows=shown,
    )
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(report, indent=1))
    print(json.dumps({k: v for k, v in report.items() if k not in ("rows", "settings")}))
    print(args.out)


if __name__ == "__main__":
    main()
