"""Throughput of the compiled play kernel against the JAX scan, Numba and plain C, forward and backward.

Fused PI output, float32, n = 32 plays, on two cases: a single long signal (T = 10^6) and a batch
(B = 256 signals of T = 2*10^4). Rows:

- `kernel`: `PIOperator(..., method="kernel")` under `jit` (`vmap` for the batch: one kernel call,
  the batch split across the CPU cores);
- `default`: `PIOperator(...)` as a user writes it, without a method (what runs by default);
- `jax_scan`: the same operator with the pure-JAX `lax.scan` (`method="scan"`);
- `numba`: the same loop under `@njit(fastmath=True)` (single signal) and `@njit(parallel=True)`
  with `prange` over the batch;
- `c_O3`: the same loop in C, compiled here with `cc -O3` and called through ctypes (one signal
  after another for the batch); `c_O3_fast_native` adds `-march=native -ffast-math`, which lets
  the compiler vectorise the sum over plays, for reference.

Backward: the reverse-mode gradient of <g, y> with respect to the input, thresholds, weights and
initial states, as `jit(grad)` (forward pass with residuals plus backward pass), for the kernel and
the scan; `kernel_vjp` times the kernel's backward pass alone (residuals precomputed). Forward
mode: `jit(jvp)` along one tangent in all four arguments (the output and its tangent), for the
kernel (`kernel_jvp`) and the scan (`jax_scan_jvp`).

The kernel rows run the build this CPU gets (`config.kernel_isa`: the AVX2/FMA module where the CPU
has them); `kernel_portable`, `kernel_portable_grad` and `kernel_portable_jvp` time the portable
module (the target's baseline, SSE2 on x86-64, that runs on any CPU) on the same inputs, in a
subprocess started with `PIEST_KERNEL_ISA=portable` (one process registers one of the two).

Every row is timed in interleaved rounds (per round and row, an untimed call and then a timed one,
with `block_until_ready`) and reported as the minimum over rounds, which filters out the time slices
lost to other processes on a shared machine (rows slower than 1 s per call get 3 rounds and no
untimed call). The process
CPU time of each call is recorded the same way (`cpu_seconds`): on a loaded machine it is the
steadier measure of work, and the backward/forward ratios are given in both. Throughput is
samples x plays per second of wall time.

Run: python experiments/bench_kernel.py [--out experiments/results/bench_kernel.json]
[--rounds 30] [--quick]. Writes one JSON file and prints a Markdown table and the target ratios.
"""

import argparse
import ctypes
import json
import os
import platform
import subprocess
import sys
import tempfile
import time

import jax
import jax.numpy as jnp
import numpy as np

from piest_jax import PIOperator, kernel_isa, write_json
from piest_jax import kernel_available as available

N_PLAYS = 32

# Targets of the kernel (ratios, higher is better except for the backward ones).
TARGETS = {
    "single_forward_default_vs_numba": 1.0,
    "batch_forward_default_vs_numba_prange": 1.0,
    "single_forward_kernel_vs_numba": 1.0,
    "batch_forward_kernel_vs_numba_prange": 1.0,
    "single_forward_kernel_vs_c_O3": 0.6,
    "single_grad_over_forward_max": 3.0,
    "batch_grad_over_forward_max": 3.0,
    "single_forward_portable_vs_jax_scan": 1.0,
    "batch_forward_portable_vs_jax_scan": 1.0,
}

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


def _numba_loops():
    from numba import njit, prange

    @njit(fastmath=True)
    def single(u, r, w, x0, y):
        x = x0.copy()
        for t in range(u.shape[0]):
            acc = np.float32(0.0)
            for j in range(r.shape[0]):
                x[j] = max(u[t] - r[j], min(u[t] + r[j], x[j]))
                acc += w[j] * x[j]
            y[t] = acc

    @njit(fastmath=True, parallel=True)
    def batch(u, r, w, x0, y):
        for b in prange(u.shape[0]):
            x = x0.copy()
            for t in range(u.shape[1]):
                acc = np.float32(0.0)
                for j in range(r.shape[0]):
                    x[j] = max(u[b, t] - r[j], min(u[b, t] + r[j], x[j]))
                    acc += w[j] * x[j]
                y[b, t] = acc

    return single, batch


def _c_loop(tmp, extra_flags):
    src = os.path.join(tmp, "pi_loop.c")
    lib = os.path.join(tmp, f"pi_loop{len(extra_flags)}.so")
    with open(src, "w") as f:
        f.write(C_SOURCE)
    subprocess.run(["cc", "-O3", *extra_flags, "-shared", "-fPIC", src, "-o", lib], check=True)
    fn = ctypes.CDLL(lib).pi_loop
    fp = ctypes.POINTER(ctypes.c_float)
    fn.argtypes = [fp, ctypes.c_int64, fp, fp, fp, ctypes.c_int64, fp]

    def call(u, r, w, x0, y):
        def ptr(a):
            return a.ctypes.data_as(fp)

        for ub, yb in zip(np.atleast_2d(u), np.atleast_2d(y)):
            x = x0.copy()
            fn(ptr(ub), ub.shape[0], ptr(r), ptr(w), ptr(x), r.shape[0], ptr(yb))

    return call


def _jax_rows(method, batched):
    """jit-compiled forward, gradient and forward-mode tangent of the PI output by `method`.

    `method=None` builds the operator without one, as a user does: the default path.
    """

    def forward(u, r, w, x0):
        op = PIOperator(r, w, x0) if method is None else PIOperator(r, w, x0, method=method)
        return op(u)

    def loss(u, r, w, x0, g):
        return jnp.vdot(g, forward(u, r, w, x0))

    def tangent(u, r, w, x0, du):
        # One direction in every argument at once.
        return jax.jvp(forward, (u, r, w, x0), (du, r, w, x0))

    fwd, grad, jvp = forward, jax.grad(loss, argnums=(0, 1, 2, 3)), tangent
    if batched:
        fwd = jax.vmap(fwd, in_axes=(0, None, None, None))
        grad = jax.vmap(grad, in_axes=(0, None, None, None, 0))
        jvp = jax.vmap(jvp, in_axes=(0, None, None, None, 0))
    return jax.jit(fwd), jax.jit(grad), jax.jit(jvp)


def _inputs(t_single, batch, seed):
    """Thresholds, weights, states and, per case, the input and the output cotangent/tangent."""
    rng = np.random.default_rng(seed)
    r = np.linspace(0.0, 1.5, N_PLAYS).astype(np.float32)
    w = rng.uniform(0.1, 1.0, N_PLAYS).astype(np.float32)
    x0 = np.zeros(N_PLAYS, np.float32)
    b_batch, t_batch = batch
    u1 = np.cumsum(rng.normal(0, 0.1, t_single)).astype(np.float32)
    ub = np.cumsum(rng.normal(0, 0.1, (b_batch, t_batch)), axis=1).astype(np.float32)
    cases = {name: (u, rng.normal(size=u.shape).astype(np.float32)) for name, u in (("single", u1), ("batch", ub))}
    return r, w, x0, cases


def _kernel_rows(u, r, w, x0, g):
    """The kernel's rows on one case: forward, jit(grad), the backward pass alone, jit(jvp)."""
    batched = u.ndim == 2
    fwd, grad, jvp = _jax_rows("kernel", batched)
    return {
        "kernel": lambda: fwd(u, r, w, x0),
        "kernel_grad": lambda: grad(u, r, w, x0, g),
        "kernel_vjp": _vjp_only(batched)(u, r, w, x0, g),
        "kernel_jvp": lambda: jvp(u, r, w, x0, g),
    }


def _portable_seconds(t_single, batch, rounds, seed):
    """The kernel rows of the portable build, timed in a subprocess on the same inputs."""
    cmd = [sys.executable, __file__, "--portable-rows", json.dumps([t_single, list(batch), rounds, seed])]
    env = {**os.environ, "PIEST_KERNEL_ISA": "portable"}
    out = subprocess.run(cmd, capture_output=True, text=True, env=env, check=True)
    return json.loads(out.stdout)


def _time_portable(t_single, batch, rounds, seed):
    if kernel_isa() != ():
        raise SystemExit(f"expected the portable kernel, got {kernel_isa()}")
    r, w, x0, cases = _inputs(t_single, tuple(batch), seed)
    results = {}
    for case, (u, g) in cases.items():
        rows = _kernel_rows(*(jnp.asarray(a) for a in (u, r, w, x0, g)))
        seconds, cpu_seconds = _time_rows(rows, rounds)
        results[case] = {"seconds": seconds, "cpu_seconds": cpu_seconds}
    return results


def _vjp_only(batched):
    def forward(u, r, w, x0):
        return PIOperator(r, w, x0, method="kernel")(u)

    fwd = jax.vmap(forward, in_axes=(0, None, None, None)) if batched else forward
    apply = jax.jit(lambda vjp, g: vjp(g))

    def prepare(u, r, w, x0, g):
        _, vjp = jax.vjp(fwd, u, r, w, x0)
        return lambda: apply(vjp, g)

    return prepare


def _time_rows(rows, rounds, slow_s=1.0, slow_rounds=3):
    """Minimum wall time per row over interleaved rounds, after one warm-up call each.

    Rows whose warm-up call took over `slow_s` seconds (the JAX scan's gradient) get only
    `slow_rounds` rounds: their relative noise is small and they would dominate the run time.
    """
    warm = {}
    for name, fn in rows.items():
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        warm[name] = time.perf_counter() - t0
    wall = {name: float("inf") for name in rows}
    cpu = dict(wall)
    for k in range(rounds):
        for name, fn in rows.items():
            if warm[name] > slow_s and k >= slow_rounds:
                continue
            if warm[name] <= slow_s:
                # An untimed call first, so that each row is timed warm (its buffers allocated and
                # faulted in, its data in cache) rather than after whatever the previous row left.
                jax.block_until_ready(fn())
            c0, t0 = time.process_time(), time.perf_counter()
            jax.block_until_ready(fn())
            t1, c1 = time.perf_counter(), time.process_time()
            wall[name] = min(wall[name], t1 - t0)
            cpu[name] = min(cpu[name], c1 - c0)
    return wall, cpu


def run_benchmark(t_single=10**6, batch=(256, 2 * 10**4), rounds=30, seed=0):
    """Time every row on both cases.

    **Arguments:** `t_single`, the long signal's length; `batch`, (B, T) of the batch case;
    `rounds`, interleaved timing rounds; `seed`, for the random signals and parameters.

    **Returns:** a dict with, per case, `seconds` and `gelem_per_s` per row, the target `ratios`,
    and the `config`.
    """
    if not available():
        raise SystemExit("the compiled play kernel is not built; reinstall with a C++ compiler")
    load_at_start = list(os.getloadavg())
    r, w, x0, cases = _inputs(t_single, batch, seed)
    nb_single, nb_batch = _numba_loops()
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        c_plain = _c_loop(tmp, [])
        c_fast = _c_loop(tmp, ["-march=native", "-ffast-math"])
        for case, (u, g), nb_name, nb_fn in (
            ("single", cases["single"], "numba", nb_single),
            ("batch", cases["batch"], "numba_prange", nb_batch),
        ):
            batched = u.ndim == 2
            ju, jr, jw, jx0, jg = (jnp.asarray(a) for a in (u, r, w, x0, g))
            s_fwd, s_grad, s_jvp = _jax_rows("scan", batched)
            d_fwd = _jax_rows(None, batched)[0]
            y = np.empty_like(u)
            rows = {
                **_kernel_rows(ju, jr, jw, jx0, jg),
                "default": lambda f=d_fwd: f(ju, jr, jw, jx0),
                nb_name: lambda f=nb_fn: f(u, r, w, x0, y),
                "c_O3": lambda: c_plain(u, r, w, x0, y),
                "c_O3_fast_native": lambda: c_fast(u, r, w, x0, y),
                "jax_scan": lambda f=s_fwd: f(ju, jr, jw, jx0),
                "jax_scan_grad": lambda f=s_grad: f(ju, jr, jw, jx0, jg),
                "jax_scan_jvp": lambda f=s_jvp: f(ju, jr, jw, jx0, jg),
            }
            seconds, cpu_seconds = _time_rows(rows, rounds)
            results[case] = {"seconds": seconds, "cpu_seconds": cpu_seconds}
    portable = _portable_seconds(t_single, batch, rounds, seed)
    for case, res in results.items():
        for key in ("seconds", "cpu_seconds"):
            res[key].update({f"kernel_portable{k[6:]}": v for k, v in portable[case][key].items()})
        elems = cases[case][0].size * N_PLAYS
        res["gelem_per_s"] = {k: elems / v / 1e9 for k, v in res["seconds"].items()}
    s, b = results["single"]["seconds"], results["batch"]["seconds"]
    sc, bc = results["single"]["cpu_seconds"], results["batch"]["cpu_seconds"]
    ratios = {
        "single_forward_default_vs_numba": s["numba"] / s["default"],
        "batch_forward_default_vs_numba_prange": b["numba_prange"] / b["default"],
        "single_forward_kernel_vs_numba": s["numba"] / s["kernel"],
        "batch_forward_kernel_vs_numba_prange": b["numba_prange"] / b["kernel"],
        "single_forward_kernel_vs_c_O3": s["c_O3"] / s["kernel"],
        "single_grad_over_forward_max": s["kernel_grad"] / s["kernel"],
        "batch_grad_over_forward_max": b["kernel_grad"] / b["kernel"],
        "single_vjp_over_forward": s["kernel_vjp"] / s["kernel"],
        "batch_vjp_over_forward": b["kernel_vjp"] / b["kernel"],
        "single_grad_over_forward_cpu": sc["kernel_grad"] / sc["kernel"],
        "batch_grad_over_forward_cpu": bc["kernel_grad"] / bc["kernel"],
        "single_forward_kernel_vs_c_O3_fast_native": s["c_O3_fast_native"] / s["kernel"],
        "single_forward_kernel_vs_jax_scan": s["jax_scan"] / s["kernel"],
        "batch_forward_kernel_vs_jax_scan": b["jax_scan"] / b["kernel"],
        "single_grad_kernel_vs_jax_scan": s["jax_scan_grad"] / s["kernel_grad"],
        "batch_grad_kernel_vs_jax_scan": b["jax_scan_grad"] / b["kernel_grad"],
        "single_jvp_over_forward": s["kernel_jvp"] / s["kernel"],
        "batch_jvp_over_forward": b["kernel_jvp"] / b["kernel"],
        "single_jvp_kernel_vs_jax_scan": s["jax_scan_jvp"] / s["kernel_jvp"],
        "batch_jvp_kernel_vs_jax_scan": b["jax_scan_jvp"] / b["kernel_jvp"],
        "single_forward_portable_vs_jax_scan": s["jax_scan"] / s["kernel_portable"],
        "batch_forward_portable_vs_jax_scan": b["jax_scan"] / b["kernel_portable"],
        "single_grad_portable_vs_jax_scan": s["jax_scan_grad"] / s["kernel_portable_grad"],
        "batch_grad_portable_vs_jax_scan": b["jax_scan_grad"] / b["kernel_portable_grad"],
        "single_jvp_portable_vs_jax_scan": s["jax_scan_jvp"] / s["kernel_portable_jvp"],
        "batch_jvp_portable_vs_jax_scan": b["jax_scan_jvp"] / b["kernel_portable_jvp"],
        "single_forward_portable_over_kernel": s["kernel_portable"] / s["kernel"],
        "batch_forward_portable_over_kernel": b["kernel_portable"] / b["kernel"],
    }
    met = {k: (ratios[k] <= v if k.endswith("_max") else ratios[k] >= v) for k, v in TARGETS.items()}
    import numba

    results["ratios"] = ratios
    results["targets"] = {"wanted": TARGETS, "met": met}
    results["config"] = {
        "n_plays": N_PLAYS,
        "single_T": t_single,
        "batch": list(batch),
        "dtype": "float32",
        "rounds": rounds,
        "timing": "minimum wall time over interleaved rounds, each an untimed then a timed call "
        "per row (3 rounds and no untimed call for rows over 1 s)",
        "cpu_count": os.cpu_count(),
        "load_average_at_start": load_at_start,
        "load_average_at_end": list(os.getloadavg()),
        "process_nice": os.nice(0),
        "machine": platform.machine(),
        "python": sys.version.split()[0],
        "jax": jax.__version__,
        "numba": numba.__version__,
        "numba_threads": numba.get_num_threads(),
        "kernel_threads": os.environ.get("PIEST_KERNEL_THREADS", "all cores"),
        "kernel_isa": list(kernel_isa()),
    }
    return results


def markdown_table(results) -> str:
    """The forward and backward throughput of every row, as a Markdown table (G elements/s)."""
    lines = [
        "| row | single forward | single backward | single jvp | batch forward | batch backward | batch jvp |",
        "|---|---|---|---|---|---|---|",
    ]
    s, b = results["single"]["gelem_per_s"], results["batch"]["gelem_per_s"]

    def cell(d, k):
        return f"{d[k]:.2f}" if k in d else "–"

    for label, fwd_s, fwd_b, grad, jvp in (
        ("default PIOperator", "default", "default", None, None),
        ("compiled kernel", "kernel", "kernel", "kernel_grad", "kernel_jvp"),
        (
            "compiled kernel, portable build",
            "kernel_portable",
            "kernel_portable",
            "kernel_portable_grad",
            "kernel_portable_jvp",
        ),
        ("JAX lax.scan", "jax_scan", "jax_scan", "jax_scan_grad", "jax_scan_jvp"),
        ("Numba njit(fastmath) / prange", "numba", "numba_prange", None, None),
        ("C -O3 (ctypes)", "c_O3", "c_O3", None, None),
        ("C -O3 -march=native -ffast-math", "c_O3_fast_native", "c_O3_fast_native", None, None),
    ):
        lines.append(
            f"| {label} | {cell(s, fwd_s)} | {cell(s, grad) if grad else '–'} | {cell(s, jvp) if jvp else '–'} | "
            f"{cell(b, fwd_b)} | {cell(b, grad) if grad else '–'} | {cell(b, jvp) if jvp else '–'} |"
        )
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="experiments/results/bench_kernel.json")
    ap.add_argument("--rounds", type=int, default=30)
    ap.add_argument("--quick", action="store_true", help="small sizes, a smoke test")
    ap.add_argument("--portable-rows", help=argparse.SUPPRESS)  # the subprocess of the portable rows
    args = ap.parse_args(argv)
    if args.portable_rows:
        print(json.dumps(_time_portable(*json.loads(args.portable_rows))))
        return 0
    sizes = {"t_single": 10**5, "batch": (32, 2 * 10**3)} if args.quick else {}
    results = run_benchmark(rounds=args.rounds, **sizes)
    write_json(args.out, results)
    print(markdown_table(results))
    print()
    for k, v in results["ratios"].items():
        tag = ""
        if k in TARGETS:
            tag = f"  target {'<=' if k.endswith('_max') else '>='} {TARGETS[k]}: " + (
                "met" if results["targets"]["met"][k] else "NOT met"
            )
        print(f"{k:40s} {v:6.2f}{tag}")
    print(args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
