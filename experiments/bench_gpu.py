"""The play bank and the creep lags on an accelerator: sequential scan against associative scan.

On a CPU the sequential `lax.scan` (or the compiled kernel) wins: the associative scan does
O(T log T) work for its O(log T) depth. On a GPU one step of a sequential scan is one pass of a
loop that the device runs one sample at a time, so the associative form, which hands the device
the whole record at once, can win where the batch is too small to fill the chip. This script
measures where each wins, on whatever backend JAX finds (it records which):

- `check`: on fresh random inputs, both methods against a float64 NumPy loop (relative error of
  the PI output) and against each other (the play outputs must agree to the last bit, as the
  operator's docstring says);
- `single`: one signal, T = 10^4 ... 10^7 samples, 32 plays, the fused PI output;
- `batch`: B signals of 10^4 samples under `vmap`, B = 1 ... 4096 (the scan's steps then carry
  B x 32 plays each);
- `lags`: the creep operator's lag bank (3 lags), one signal, T = 10^5 ... 10^7.

Each time is the median of `--repeats` calls after a compiling warm-up, with the result brought
to the host (`block_until_ready`); inputs are drawn afresh for each size. Throughput is given in
G element-steps per second (samples x plays / s). Sizes whose single call would run longer than
`--budget` seconds (extrapolated from the previous size) are skipped and listed.

Run: python experiments/bench_gpu.py [--quick] [--dtype float32|float64] [--out FILE]
"""

import argparse
import json
import os
import platform
import statistics
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
N_PLAYS = 32
N_LAGS = 3
METHODS = ("scan", "associative")


def _numpy_pi(u, r, w):
    """The PI output by the plain recurrence, float64, plays starting at 0."""
    x = np.zeros(len(r))
    y = np.empty(len(u))
    for t, ut in enumerate(u):
        x = np.maximum(ut - r, np.minimum(ut + r, x))
        y[t] = x @ w
    return y


def _signal(rng, shape, dtype):
    # A random walk with reversals of every size, scaled to about [-1, 1].
    steps = rng.normal(0.0, 1.0, shape)
    u = np.cumsum(steps, axis=-1)
    u = u / np.max(np.abs(u), axis=-1, keepdims=True)
    return jnp.asarray(u, dtype)


def _median_seconds(fn, arg, repeats):
    jax.block_until_ready(fn(arg))
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(arg))
        times.append(time.perf_counter() - t0)
    return statistics.median(times), times


def _operator(method, dtype):
    from piest_jax import PIOperator

    r = jnp.linspace(0.0, 0.9, N_PLAYS, dtype=dtype)
    w = jnp.full(N_PLAYS, 1.0 / N_PLAYS, dtype)
    return PIOperator(r, w, method=method)


def check(rng, dtype):
    """Both methods against the NumPy loop and against each other, on fresh inputs."""
    from piest_jax import play

    rows = []
    for T in (1000, 20_000):
        u = _signal(rng, (T,), dtype)
        r = jnp.asarray(np.sort(rng.uniform(0.0, 0.9, N_PLAYS)), dtype).at[0].set(0.0)
        w = jnp.asarray(rng.uniform(0.1, 1.0, N_PLAYS), dtype)
        ref = _numpy_pi(np.asarray(u, np.float64), np.asarray(r, np.float64), np.asarray(w, np.float64))
        banks = {m: np.asarray(jax.jit(lambda u, r, m=m: play(u, r, 0.0, method=m))(u, r)) for m in METHODS}
        row = {"samples": T, "plays_equal_bitwise": bool(np.array_equal(banks["scan"], banks["associative"]))}
        for m in METHODS:
            y = banks[m].astype(np.float64) @ np.asarray(w, np.float64)
            row[f"{m}_relative_error"] = float(np.linalg.norm(y - ref) / np.linalg.norm(ref))
        rows.append(row)
        print(
            f"check T={T}: bitwise equal {row['plays_equal_bitwise']}, "
            f"scan {row['scan_relative_error']:.1e}, associative {row['associative_relative_error']:.1e}"
        )
    return rows


def _sweep(label, sizes, make, budget, repeats):
    """Time `make(size, method) -> (fn, arg, element_steps)` over sizes, for both methods."""
    rows, skipped = [], []
    for m in METHODS:
        last = None
        for size in sizes:
            if last is not None and last[1] * size / last[0] > budget:
                skipped.append({"method": m, "size": size})
                continue
            fn, arg, work = make(size, m)
            sec, times = _median_seconds(fn, arg, repeats)
            last = (size, sec)
            rows.append(
                {
                    "method": m,
                    "size": size,
                    "seconds": sec,
                    "all_seconds": times,
                    "g_element_steps_per_s": work / sec / 1e9,
                }
            )
            print(f"{label} {m:11s} size {size:>8d}: {sec * 1e3:9.2f} ms, {work / sec / 1e9:8.3f} G/s")
            del fn, arg
    return rows, skipped


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small sizes, for a smoke test")
    ap.add_argument("--dtype", default="float32", choices=("float32", "float64"))
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--budget", type=float, default=20.0, help="skip calls longer than this (s)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=os.path.join(HERE, "results", "bench_gpu.json"))
    args = ap.parse_args()
    if args.dtype == "float64":
        # An experiment script, not library code: float64 rows need x64 switched on.
        jax.config.update("jax_enable_x64", True)
    dtype = jnp.dtype(args.dtype)
    rng = np.random.default_rng(args.seed)
    dev = jax.devices()[0]
    print(f"backend {jax.default_backend()}, device {dev.device_kind}, jax {jax.__version__}")

    singles = [10**3, 10**4] if args.quick else [10**4, 10**5, 10**6, 10**7]
    batches = [1, 8] if args.quick else [1, 8, 64, 512, 4096]
    batch_T = 1000 if args.quick else 10_000
    lag_sizes = [10**3, 10**4] if args.quick else [10**5, 10**6, 10**7]

    def single(T, m):
        op = _operator(m, dtype)
        return eqx.filter_jit(op), _signal(rng, (T,), dtype), T * N_PLAYS

    def batch(B, m):
        op = _operator(m, dtype)
        return eqx.filter_jit(jax.vmap(op)), _signal(rng, (B, batch_T), dtype), B * batch_T * N_PLAYS

    def lags(T, m):
        from piest_jax import Creep

        # Time constants of 30, 300 and 3000 samples, the creep of a record sampled at 1 kHz.
        cr = Creep(jnp.asarray([0.03, 0.3, 3.0], dtype), jnp.asarray([1.0, -0.5, 0.2], dtype), 1e-3, method=m)
        return eqx.filter_jit(cr.states), _signal(rng, (T,), dtype), T * N_LAGS

    out = {
        "backend": jax.default_backend(),
        "device": dev.device_kind,
        "jax": jax.__version__,
        "python": platform.python_version(),
        "dtype": args.dtype,
        "plays": N_PLAYS,
        "lags": N_LAGS,
        "batch_samples": batch_T,
        "repeats": args.repeats,
        "check": check(rng, dtype),
    }
    for label, sizes, make in (("single", singles, single), ("batch", batches, batch), ("lags", lag_sizes, lags)):
        rows, skipped = _sweep(label, sizes, make, args.budget, args.repeats)
        out[label] = rows
        out[f"{label}_skipped"] = skipped
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    with open(args.out, "w") as f:
        json.dump(out, f, indent=1)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
