"""Throughput of the compiled play kernel against Numba, plain C and the JAX scan, in one run.

Fused PI output, float32, n = 32 plays: a single long signal (T = 10^6) and a batch
(B = 256 signals of T = 2*10^4). Rows: the kernel (`method="kernel"`, forward and reverse-mode
gradient wrt input, thresholds, weights and initial states), the pure-JAX scan, a Numba
`@njit(fastmath=True)` loop (`prange` over the batch), and the same loop written in C, compiled
here with `gcc -O3` and called through ctypes. Every timing is the minimum over repeats after one
warm-up call, with `block_until_ready`; throughput is samples x plays per second.

Run: python experiments/bench_kernel.py [--out experiments/results/bench_kernel.json] [--quick]
Writes one JSON file and prints a table.
"""

import argparse
import ctypes
import json
import os
import subprocess
import tempfile
import time

import jax
import jax.numpy as jnp
import numpy as np

from piest_jax import PIOperator
from piest_jax._kernel import available

C_SOURCE = r"""
#include <stdint.h>
void pi_loop(const float* u, int64_t T, const float* r, const float* w, float* x, int64_t n,
             float* y) {
  for (int64_t t = 0; t < T; ++t) {
    float acc = 0.0f;
    for (int64_t j = 0; j < n; ++j) {
      float hi = u[t] + r[j], lo = u[t] - r[j];
      float m = hi < x[j] ? hi : x[j];
      x[j] = lo > m ? lo : m;
      acc += w[j] * x[j];
    }
    y[t] = acc;
  }
}
"""


def _min_time(fn, repeats):
    fn()
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def _numba_fns():
    from numba import njit, prange

    @njit(fastmath=True)
    def pi_loop(u, r, w, x0, y):
        x = x0.copy()
        for t in range(u.shape[0]):
            acc = np.float32(0.0)
            for j in range(r.shape[0]):
                x[j] = max(u[t] - r[j], min(u[t] + r[j], x[j]))
                acc += w[j] * x[j]
            y[t] = acc

    @njit(fastmath=True, parallel=True)
    def pi_batch(u, r, w, x0, y):
        for b in prange(u.shape[0]):
            x = x0.copy()
            for t in range(u.shape[1]):
                acc = np.float32(0.0)
                for j in range(r.shape[0]):
                    x[j] = max(u[b, t] - r[j], min(u[b, t] + r[j], x[j]))
                    acc += w[j] * x[j]
                y[b, t] = acc

    return pi_loop, pi_batch


def _c_fn(tmp):
    src = os.path.join(tmp, "pi_loop.c")
    lib = os.path.join(tmp, "pi_loop.so")
    with open(src, "w") as f:
        f.write(C_SOURCE)
    subprocess.run(["gcc", "-O3", "-shared", "-fPIC", src, "-o", lib], check=True)
    fn = ctypes.CDLL(lib).pi_loop
    fp = ctypes.POINTER(ctypes.c_float)
    fn.argtypes = [fp, ctypes.c_int64, fp, fp, fp, ctypes.c_int64, fp]

    def call(u, r, w, x0, y):
        x = x0.copy()
        p = lambda a: a.ctypes.data_as(fp)  # noqa: E731
        fn(p(u), u.shape[0], p(r), p(w), p(x), r.shape[0], p(y))

    return call


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="experiments/results/bench_kernel.json")
    ap.add_argument("--quick", action="store_true", help="smaller sizes, for a smoke test")
    ap.add_argument("--repeats", type=int, default=7)
    args = ap.parse_args(argv)
    if not available():
        raise SystemExit("the compiled play kernel is not built; reinstall with a C++ compiler")

    n = 32
    t_single, (b_batch, t_batch) = (10**6, (256, 2 * 10**4))
    if args.quick:
        t_single, (b_batch, t_batch) = (10**5, (32, 2 * 10**3))
    rng = np.random.default_rng(0)
    r = np.linspace(0.0, 1.5, n).astype(np.float32)
    w = rng.uniform(0.1, 1.0, n).astype(np.float32)
    x0 = np.zeros(n, np.float32)
    u1 = np.cumsum(rng.normal(0, 0.1, t_single)).astype(np.float32)
    ub = np.cumsum(rng.normal(0, 0.1, (b_batch, t_batch)), axis=1).astype(np.float32)

    ops = {m: PIOperator(r, w, x0, method=m) for m in ("kernel", "scan")}
    fwd = {m: jax.jit(lambda u, op=op: op(u)) for m, op in ops.items()}
    fwd_b = {m: jax.jit(jax.vmap(lambda u, op=op: op(u))) for m, op in ops.items()}

    def loss(params, u, method):
        rr, ww, xx = params
        return jnp.sum(PIOperator(rr, ww, xx, method=method)(u) ** 2)

    grad1 = jax.jit(jax.grad(lambda p, u: loss(p, u, "kernel"), argnums=(0, 1)))
    grad_b = jax.jit(
        jax.grad(lambda p, u: jnp.sum(jax.vmap(lambda v: loss(p, v, "kernel"))(u)), argnums=(0, 1))
    )
    params = tuple(jnp.asarray(a) for a in (r, w, x0))
    ju1, jub = jnp.asarray(u1), jnp.asarray(ub)

    nb_loop, nb_batch = _numba_fns()
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        c_loop = _c_fn(tmp)
        y1 = np.empty_like(u1)
        yb = np.empty_like(ub)
        rep = args.repeats
        single = {
            "kernel": _min_time(lambda: fwd["kernel"](ju1).block_until_ready(), rep),
            "kernel_grad": _min_time(lambda: jax.block_until_ready(grad1(params, ju1)), rep),
            "numba": _min_time(lambda: nb_loop(u1, r, w, x0, y1), rep),
            "c_O3": _min_time(lambda: c_loop(u1, r, w, x0, y1), rep),
            "jax_scan": _min_time(lambda: fwd["scan"](ju1).block_until_ready(), max(2, rep // 3)),
        }
        batch = {
            "kernel": _min_time(lambda: fwd_b["kernel"](jub).block_until_ready(), rep),
            "kernel_grad": _min_time(lambda: jax.block_until_ready(grad_b(params, jub)), rep),
            "numba_prange": _min_time(lambda: nb_batch(ub, r, w, x0, yb), rep),
            "jax_scan": _min_time(lambda: fwd_b["scan"](jub).block_until_ready(), max(2, rep // 3)),
        }
    for name, times, elems in (
        ("single", single, t_single * n),
        ("batch", batch, b_batch * t_batch * n),
    ):
        results[name] = {
            "seconds": times,
            "gelem_per_s": {k: elems / v / 1e9 for k, v in times.items()},
        }
    s, b = single, batch
    results["ratios"] = {
        "single_kernel_over_numba": s["numba"] / s["kernel"],
        "single_kernel_over_c_O3": s["c_O3"] / s["kernel"],
        "single_grad_over_forward": s["kernel_grad"] / s["kernel"],
        "batch_kernel_over_numba_prange": b["numba_prange"] / b["kernel"],
        "batch_grad_over_forward": b["kernel_grad"] / b["kernel"],
        "single_kernel_over_jax_scan": s["jax_scan"] / s["kernel"],
        "batch_kernel_over_jax_scan": b["jax_scan"] / b["kernel"],
    }
    results["config"] = {
        "n_plays": n,
        "single_T": t_single,
        "batch": [b_batch, t_batch],
        "dtype": "float32",
        "repeats": args.repeats,
        "cpu_count": os.cpu_count(),
        "jax": jax.__version__,
    }
    os.makedirs(os.path.dirname(args.out) or ".", exist_ok=True)
    with open(args.out, "w") as f:
        json.dump(results, f, indent=2)
    for name in ("single", "batch"):
        for k, v in results[name]["gelem_per_s"].items():
            print(f"{name:7s} {k:14s} {v:7.2f} G elem/s")
    for k, v in results["ratios"].items():
        print(f"{k:34s} {v:6.2f}")
    print(args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
