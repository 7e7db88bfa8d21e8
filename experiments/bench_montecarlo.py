"""Throughput of the Monte Carlo PE map (`piest_jax.pe_map`).

The headline case is the one the map is sized for: 10,000 draws x 5,000 samples x 10 plays, every
draw with its windowed PE levels (window T0 = 1,000 samples every 100 samples: 41 windows, each
with its Gram matrix and eigenvalues), the Assumption 1 ratio, the excited plays per window, the
sharper condition and the RLS weight error. Families take turns (all seven).

Rows:

- `headline`: the full case, wall time of `pe_map` after a compiling warm-up call (same settings
  and chunk size, so the timed run reuses the compiled program), and the first-call time
  (compilation included) separately;
- `stages`: where the time goes, on one chunk: cumulative jitted programs (draw the cases; + the
  play bank; + the windowed statistics; + eigenvalues and the RLS error = everything), each
  run the way the engine runs it (a few draws at a time), and the same full computation as one
  `vmap` over the chunk, the layout the engine used before;
- `scaling_draws`: the same settings for fewer draws (one compiled program);
- `scaling_samples`: T = 1,250, 2,500, 5,000 at a fixed number of draws (window T/5, stride
  T/50: one compile each);
- `chunks`: the headline settings at a few chunk sizes.

Throughput is draws per second and sample-plays per second (draws x T x n / seconds). Each row
also has `cpu_seconds` (the process's CPU time over all its threads) and the load average before
and after, since the machine may be shared: with other jobs running, wall time exceeds CPU time.

Run: python experiments/bench_montecarlo.py [--quick] [--dtype float32|float64]
     [--play-method scan|associative|kernel|auto] [--chunk N] [--no-stages] [--host-devices N]
     [--out FILE]

`--host-devices N` splits the CPU into N JAX devices
(XLA_FLAGS=--xla_force_host_platform_device_count=N), so the engine shards the draws over them.
"""

import argparse
import functools
import os
import platform
import sys
import time


def _early_devices(argv) -> None:
    # The device count is fixed when JAX starts, so it is read before importing it.
    if "--host-devices" in argv:
        count = argv[argv.index("--host-devices") + 1]
        flags = os.environ.get("XLA_FLAGS", "")
        os.environ["XLA_FLAGS"] = f"{flags} --xla_force_host_platform_device_count={count}".strip()


_early_devices(sys.argv)

import jax  # noqa: E402
from jax import lax  # noqa: E402

# An experiment script, not library code: float64 rows need x64 switched on.
jax.config.update("jax_enable_x64", True)

from piest_jax import (  # noqa: E402
    draw_case,
    draw_keys,
    draw_statistics,
    make_settings,
    numerical_tolerance,
    pe_map,
    play,
    sharper_condition,
    summarise,
    write_json,
)

HERE = os.path.dirname(os.path.abspath(__file__))


def _load() -> list[float]:
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except OSError:
        return []


def _settings(T, n, dtype, method):
    return make_settings(n_samples=T, n_plays=n, window=T // 5, stride=T // 50, dtype=dtype, play_method=method)


def _clock(fn):
    load_before = _load()
    c0, t0 = time.process_time(), time.perf_counter()
    out = fn()
    seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
    return out, {"seconds": seconds, "cpu_seconds": cpu, "load_before": load_before, "load_after": _load()}


def _timed(key, draws, settings, chunk):
    res, clock = _clock(lambda: pe_map(key, draws, settings, chunk=chunk, quiet=True))
    T, n = settings.n_samples, settings.n_plays
    return res, {
        "draws": draws,
        "samples": T,
        "plays": n,
        "chunk": chunk,
        **clock,
        "draws_per_s": draws / clock["seconds"],
        "sample_plays_per_s": draws * T * n / clock["seconds"],
    }


def _stages(key, settings, count):
    """Cumulative programs on `count` draws of the first family, the best of three runs each."""
    s = settings
    t = s.times()
    keys = draw_keys(key, 0, count)
    # One draw per step, as `pe_map` runs them.
    per_step = functools.partial(lax.map, batch_size=1)
    family = s.families[0]

    def case(k):
        return draw_case(k, family, t, s.n_plays)

    def bank(k):
        u, r, x0, _ = case(k)
        return play(u, r, x0, method=s.play_method)

    def windows(k):
        u, r, x0, _ = case(k)
        H = play(u, r, x0, method=s.play_method)
        return sharper_condition(H, u, s.window, stride=s.stride, rtol=numerical_tolerance(u.dtype))

    def full(k):
        return draw_statistics(*case(k), settings=s)

    programs = {
        "draw cases": jax.jit(lambda ks: per_step(case, ks)),
        "+ play bank": jax.jit(lambda ks: per_step(bank, ks)),
        "+ windowed statistics": jax.jit(lambda ks: per_step(windows, ks)),
        "+ eigenvalues and RLS (all)": jax.jit(lambda ks: per_step(full, ks)),
        "all, one vmap over the chunk": jax.jit(jax.vmap(full)),
    }
    rows = []
    for name, fn in programs.items():
        jax.block_until_ready(fn(keys))
        best = min(
            (_clock(lambda: jax.block_until_ready(fn(keys)))[1] for _ in range(3)), key=lambda c: c["cpu_seconds"]
        )
        rows.append({"stage": name, "draws": count, **best})
        print(f"stage {name}: {best['seconds']:.2f} s wall, {best['cpu_seconds']:.2f} s CPU")
    return rows


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="small sizes: a smoke test")
    p.add_argument("--dtype", default="float64", choices=("float32", "float64"))
    p.add_argument("--play-method", default="auto", choices=("scan", "associative", "kernel", "auto"))
    p.add_argument(
        "--no-stages", action="store_true", help="skip the per-stage rows (one draw per step: slow on accelerators)"
    )
    p.add_argument("--chunk", type=int, default=1000)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--host-devices", type=int, help="CPU devices to shard over (read at start)")
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
    warm_key = jax.random.fold_in(key, 1)
    _, first = _clock(lambda: pe_map(warm_key, chunk, s, chunk=chunk, quiet=True))
    res, row = _timed(key, draws, s, chunk)
    row["first_call_seconds"] = first["seconds"]
    row["windows_per_draw"] = (T - s.window) // s.stride + 1
    summary = summarise(res)
    row["map"] = {
        k: summary[k]
        for k in (
            "n",
            "tolerance",
            "assumption_holds",
            "pe",
            "theorem_violations",
            "theorem_violations_failing_sharper",
            "pe_below_assumption",
            "pe_fraction_below_assumption",
            "sharper_holds",
            "sharper_holds_not_pe",
            "sharper_fails_pe",
        )
    }
    row["map"]["sharper_condition"] = {
        k: summary["sharper_condition"][k] for k in ("violations", "holds_but_not_pe", "fails_but_pe")
    }
    report["headline"] = row
    print(
        f"headline: {draws} x {T} x {n} in {row['seconds']:.2f} s "
        f"({row['draws_per_s']:.0f} draws/s, {row['cpu_seconds']:.1f} s CPU; "
        f"first call {first['seconds']:.1f} s; load {row['load_after']})"
    )

    if not args.no_stages:
        report["stages"] = _stages(key, s, chunk)

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
    for c in (250, 2000):
        c = min(c, draws)
        pe_map(jax.random.fold_in(key, 1), c, s, chunk=c, quiet=True)
        _, r = _timed(key, max(d, c), s, c)
        report["chunks"].append(r)
        print(f"chunk {c}: {r['seconds']:.2f} s for {max(d, c)} draws")

    print(write_json(args.out, report))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
