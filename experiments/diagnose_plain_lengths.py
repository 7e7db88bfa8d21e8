"""`piest diagnose`'s search across lengths: plain-PI records, or records with one hidden effect.

    python experiments/diagnose_plain_lengths.py [--lengths 1e4,1e5,1e6] [--seeds 10]
        ->  experiments/results/diagnose_plain_lengths.json
    python experiments/diagnose_plain_lengths.py --hidden all --seeds 1 [--noise-ar 0]
        ->  experiments/results/diagnose_hidden_lengths.json

Records from the hidden-effect generator with no effect (`hidden_effect_record(())`), white noise
and AR(1) noise with φ = 0.8, each length with the same seeds (fewer at the longest, which
take longest). A right diagnosis names nothing: more samples must not turn the plain model's
small mismatch or coloured noise into a named effect. Each row: the effects named, the time, the
true noise std, the final RMSE and the plain model's held-out RMSE. With `--hidden`, each record
hides one effect (each of the names given, or `all`), white noise unless `--noise-ar`; a right
diagnosis names exactly that effect, at every length.
"""

import argparse
import json
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import piest_jax as pj  # noqa: E402

OUT = Path(__file__).parent / "results" / "diagnose_plain_lengths.json"


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--lengths", default="1e4,1e5,1e6")
    p.add_argument(
        "--seeds",
        type=int,
        default=10,
        help="records per length and noise (one fewer at the longest); with --hidden, per effect and length",
    )
    p.add_argument("--hidden", help="comma-separated effects to hide one at a time, or `all`")
    p.add_argument("--noise-ar", type=float, default=0.0, help="with --hidden: the noise's AR(1) phi")
    p.add_argument("--out")
    args = p.parse_args(argv)
    lengths = sorted(int(float(s)) for s in args.lengths.split(","))
    if args.hidden:
        return hidden(args, lengths)
    args.out = args.out or str(OUT)
    rows = []
    for T in lengths:
        for ar in (0.0, 0.8):
            for seed in range(args.seeds if T < lengths[-1] or len(lengths) == 1 else max(1, args.seeds - 1)):
                rec, truth = pj.hidden_effect_record((), key=jax.random.PRNGKey(1000 + seed), n_samples=T, noise_ar=ar)
                t0 = time.perf_counter()
                d = pj.diagnose(rec, quiet=True)
                rows.append(
                    dict(
                        n_samples=T,
                        noise_ar=ar,
                        seed=1000 + seed,
                        effects=d.effects,
                        seconds=time.perf_counter() - t0,
                        noise_std=truth["noise_std"],
                        final_rmse=d.final_rmse,
                        heldout_baseline_rmse=d.heldout_baseline_rmse,
                    )
                )
                print(json.dumps(rows[-1]), flush=True)
    named_nothing = sum(not r["effects"] for r in rows)
    res = dict(records=len(rows), named_nothing=named_nothing, runs=rows)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(res, indent=1))
    print(f"{named_nothing}/{len(rows)} named nothing; {args.out}")


def hidden(args, lengths):
    names = pj.EFFECTS if args.hidden == "all" else tuple(args.hidden.split(","))
    rows = []
    for T in lengths:
        for effect in names:
            for seed in range(args.seeds):
                rec, truth = pj.hidden_effect_record(
                    (effect,), key=jax.random.PRNGKey(2000 + seed), n_samples=T, noise_ar=args.noise_ar
                )
                t0 = time.perf_counter()
                d = pj.diagnose(rec, quiet=True)
                rows.append(
                    dict(
                        n_samples=T,
                        hidden=effect,
                        seed=2000 + seed,
                        effects=d.effects,
                        right=list(d.effects) == [effect],
                        seconds=time.perf_counter() - t0,
                        noise_std=truth["noise_std"],
                        final_rmse=d.final_rmse,
                        heldout_baseline_rmse=d.heldout_baseline_rmse,
                    )
                )
                print(json.dumps(rows[-1]), flush=True)
    right = sum(r["right"] for r in rows)
    by_length = {
        T: f"{sum(r['right'] for r in rows if r['n_samples'] == T)}/{sum(r['n_samples'] == T for r in rows)}"
        for T in lengths
    }
    res = dict(records=len(rows), right=right, right_by_length=by_length, noise_ar=args.noise_ar, runs=rows)
    out = args.out or str(OUT.with_name("diagnose_hidden_lengths.json"))
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    Path(out).write_text(json.dumps(res, indent=1))
    print(f"{right}/{len(rows)} named exactly the hidden effect {by_length}; {out}")


if __name__ == "__main__":
    main()
