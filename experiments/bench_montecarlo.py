"""Throughput of the Monte Carlo PE map (`piest_jax._montecarlo.pe_map`).

The headline case is the one the map is sized for: 10,000 draws x 5,000 samples x 10 plays, every
draw with its windowed PE levels (window T0 = 1,000 samples every 100 samples: 41 windows, each
with its Gram matrix and eigenvalues), the Assumption 1 ratio, the excited plays per window, the
sharper condition and the RLS weight error. Families take turns (all seven).

Rows:

- `headline`: the full case, wall time of `pe_map` after a compiling warm-up call (same settings
  and chunk size, so the timed run reuses the compiled program), and the first-call time
  (compilation included) separately;
- `scaling_draws`: the same settings for fewer draws (one compiled program);
- `scaling_samples`: T = 1,250, 2,500, 5,000 at a fixed number of draws (window T/5, stride
  T/50: one compile each);
- `chunks`: the headline settings at a few chunk sizes on a smaller number of draws.

Throughput is draws per second and sample-plays per second (draws x T x n / seconds). The JSON
records the load average before and after each timed run, since the machine may be shared.

Run: python experiments/bench_montecarlo.py [--quick] [--dtype float32|float64]
     [--play-method scan|kernel|auto] [--out experiments/results/bench_montecarlo.json]
"""

import argparse
import os
import platform
import time

import jax

# An experiment script, not library code: float64 rows need x64 switched on.
jax.config.update("jax_enable_x64", True)


from piest_jax import _io  # noqa: E402
from piest_jax._montecarlo import make_settings, pe_map, summarise  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))


def _load() -> list[float]:
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except OSError:
        return []


def _settings(T, n, dtype, method):
    return make_settings(
        n_samples=T, n_plays=n, window=T // 5, stride=T // 50, dtype=dtype, play_method=method
    )


def _timed(key, draws, settings, chunk):
    load_before = _load()
    t0 = time.perf_counter()
    res = pe_map(key, draws, settings, chunk=chunk, quiet=True)
    seconds = time.perf_counter() - t0
    T, n = settings.n_samples, settings.n_plays
    return res, {
        "draws": draws,
        "samples": T,
        "plays": n,
        "chunk": chunk,
        "seconds": seconds,
        "draws_per_s": draws / seconds,
        "sample_plays_per_s": draws * T * n / seconds,
        "load_before": load_before,
        "load_after": _load(),
    }


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="small sizes: a smoke test")
    p.add_argument("--dtype", default="float64", choices=("float32", "float64"))
    p.add_argument("--play-method", default="auto", choices=("scan", "kernel", "auto"))
    p.add_argument("--chunk", type=int, default=1000)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default=os.path.join(HERE, "results", "bench_montecarlo.json"))
    args = p.parse_args(argv)

    draws, T, n = (700, 1000, 10) if args.quick else (10_000, 5_000, 10)
    key = jax.random.key(args.seed)
    report = {
        "machine": {
            "platform": platform.platform(),
            "cpu_count": os.cpu_count(),
            "devices": [str(d) for d in jax.devices()],
            "jax": jax.__version__,
        },
        "dtype": args.dtype,
        "play_method": args.play_method,
        "target": "10,000 draws x 5,000 samples x 10 plays in under 20 s on a 2-core CPU",
    }

    s = _settings(T, n, args.dtype, args.play_method)
    chunk = min(args.chunk, draws)
    t0 = time.perf_counter()
    pe_map(jax.random.fold_in(key, 1), chunk, s, chunk=chunk, quiet=True)
    first = time.perf_counter() - t0
    res, row = _timed(key, draws, s, chunk)
    row["first_call_seconds"] = first
    row["windows_per_draw"] = (T - s.window) // s.stride + 1
    summary = summarise(res, s)
    row["map"] = {k: summary[k] for k in ("n", "assumption_holds", "pe", "theorem_violations",
                                         "pe_fraction_below_assumption")}
    row["map"]["sharper_condition"] = {
        k: summary["sharper_condition"][k] for k in ("violations", "holds_but_not_pe", "fails_but_pe")
    }
    report["headline"] = row
    print(f"headline: {draws} x {T} x {n} in {row['seconds']:.2f} s "
          f"({row['draws_per_s']:.0f} draws/s; first call {first:.1f} s; load {row['load_after']})")

    report["scaling_draws"] = []
    for d in sorted({max(chunk, draws // 10), max(chunk, draws // 3)}):
        _, r = _timed(key, d, s, chunk)
        report["scaling_draws"].append(r)
        print(f"draws {d}: {r['seconds']:.2f} s")
    report["scaling_draws"].append({k: row[k] for k in row if k != "map"})

    report["scaling_samples"] = []
    d = max(chunk, draws // 5)
    for TT in (T // 4, T // 2, T):
        ss = _settings(TT, n, args.dtype, args.play_method)
        pe_map(jax.random.fold_in(key, 1), chunk, ss, chunk=chunk, quiet=True)
        _, r = _timed(key, d, ss, chunk)
        report["scaling_samples"].append(r)
        print(f"samples {TT}: {r['seconds']:.2f} s")

    report["chunks"] = []
    for c in (250, 500, 2000):
        c = min(c, draws)
        pe_map(jax.random.fold_in(key, 1), c, s, chunk=c, quiet=True)
        _, r = _timed(key, max(d, c), s, c)
        report["chunks"].append(r)
        print(f"chunk {c}: {r['seconds']:.2f} s for {max(d, c)} draws")

    print(_io.write_json(args.out, report))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
