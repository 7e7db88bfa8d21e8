"""Throughput of the play bank and the fused PI output: JAX against NumPy and Numba loops.

Elements are samples x plays (x signals for a batch), so the figure is element-steps per second.
Cases (all in one run, float32 and float64 each):

- `single`: one long signal, T = 10^6, n = 32 plays;
- `batch`: B = 1000 signals, T = 10^4, n = 10;
- `batch_wide`: B = 256 signals, T = 2*10^4, n = 32.

Rows per case, dtype and output (`bank`: the play outputs H (B, T, n); `fused`: the PI output
y (B, T) without H):

- `numpy_loop`: a per-sample Python loop over NumPy arrays (vectorised over plays and signals);
- `numba`: the same loop under `@njit(fastmath=True)`, `prange` over the signals of a batch
  (skipped, and said so in the JSON, when numba is not installed: `pip install .[bench]`);
- `jax_scan`: `PIOperator(method="scan")` / `play(method="scan")`, `vmap` over a batch;
- `jax_associative`: the parallel-in-time form (`method="associative"`);
- `kernel`: the compiled CPU kernel (`method="kernel"`), when it was built.

Every timing is the minimum over repeats after one warm-up call that also compiles, with
`block_until_ready`. Each row also records its largest deviation from the NumPy loop's outputs.

Backward column (`grad_seconds`, fused output, `jax_scan` and `kernel` rows): `jit(vmap(grad))` of
<g, y> with respect to the input, thresholds, weights and initial states, i.e. the forward pass that
keeps what the gradient needs plus the backward pass; `grad_over_forward` divides it by the row's
forward time. The NumPy and Numba loops have no gradient; the associative scan's gradient at these
sizes holds log2(T) levels of (B, T, n) intermediates, several GB, and is left out.

Run: python experiments/bench_operators.py [--quick] [--repeats N] [--cases single,batch]
     [--out experiments/results/bench_operators.json]
"""

import argparse
import json
import os
import platform
import time

import jax

# An experiment script, not library code: float64 rows need x64 switched on.
jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from piest_jax import PIOperator, play  # noqa: E402

FULL = {"single": (1, 10**6, 32), "batch": (1000, 10**4, 10), "batch_wide": (256, 2 * 10**4, 32)}
QUICK = {"single": (1, 2 * 10**4, 32), "batch": (100, 10**3, 10), "batch_wide": (32, 2 * 10**3, 32)}


def _min_time(fn, repeats, budget=5.0):
    """Minimum wall time of `fn` over `repeats` calls after a warm-up call; slow rows stop
    repeating once `budget` seconds have been spent timing them."""
    out = fn()  # warm-up: compiles, and gives the outputs to check
    best, spent = float("inf"), 0.0
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        dt = time.perf_counter() - t0
        best, spent = min(best, dt), spent + dt
        if spent > budget:
            break
    return best, out


def numpy_loop(u, r, w, x0, fused):
    """u (B, T); r, w, x0 (n,). The defining recursion, one sample at a time."""
    x = np.broadcast_to(x0, (u.shape[0], r.shape[0])).copy()
    out = np.empty(u.shape if fused else u.shape + r.shape, dtype=u.dtype)
    for t in range(u.shape[1]):
        ut = u[:, t, None]
        np.maximum(ut - r, np.minimum(ut + r, x), out=x)
        if fused:
            out[:, t] = x @ w
        else:
            out[:, t] = x
    return out


def _numba_loops():
    try:
        from numba import njit, prange
    except ImportError:
        return None

    @njit(fastmath=True)
    def fused_one(u, r, w, x0, y):
        x = x0.copy()
        for t in range(u.shape[0]):
            acc = 0.0 * w[0]
            for j in range(r.shape[0]):
                x[j] = max(u[t] - r[j], min(u[t] + r[j], x[j]))
                acc += w[j] * x[j]
            y[t] = acc

    @njit(fastmath=True)
    def bank_one(u, r, x0, h):
        x = x0.copy()
        for t in range(u.shape[0]):
            for j in range(r.shape[0]):
                x[j] = max(u[t] - r[j], min(u[t] + r[j], x[j]))
                h[t, j] = x[j]

    # One signal is a sequential recurrence; a batch spreads its signals over the cores.
    @njit(fastmath=True, parallel=True)
    def fused_batch(u, r, w, x0, y):
        for b in prange(u.shape[0]):
            fused_one(u[b], r, w, x0, y[b])

    @njit(fastmath=True, parallel=True)
    def bank_batch(u, r, x0, h):
        for b in prange(u.shape[0]):
            bank_one(u[b], r, x0, h[b])

    def run(u, r, w, x0, is_fused):
        out = np.empty(u.shape if is_fused else u.shape + r.shape, dtype=u.dtype)
        if u.shape[0] == 1:
            if is_fused:
                fused_one(u[0], r, w, x0, out[0])
            else:
                bank_one(u[0], r, x0, out[0])
        elif is_fused:
            fused_batch(u, r, w, x0, out)
        else:
            bank_batch(u, r, x0, out)
        return out

    return run


def _kernel_status():
    # The compiled kernel is optional; a missing or unloadable build only drops its rows.
    try:
        from piest_jax import kernel_available

        return (True, "") if kernel_available() else (False, "the compiled kernel was not built")
    except Exception as e:  # an extension built from other sources can fail in many ways
        return False, f"the compiled kernel cannot be loaded ({type(e).__name__}: {e})"


def _jax_fn(method, fused, r, w, x0):
    op = PIOperator(r, w, x0, method=method)
    one = op if fused else (lambda s: play(s, r, x0, method=method))
    f = jax.jit(jax.vmap(one))
    return lambda u: jax.block_until_ready(f(u))


def _jax_grad_fn(method, r, w, x0, g):
    # Cotangent g (B, T) of the fused output; gradients w.r.t. u, thresholds, weights, states.
    def loss(u, r, w, x0, g):
        return jnp.vdot(g, PIOperator(r, w, x0, method=method)(u))

    f = jax.jit(jax.vmap(jax.grad(loss, argnums=(0, 1, 2, 3)), in_axes=(0, None, None, None, 0)))
    r, w, x0, g = (jnp.asarray(a) for a in (r, w, x0, g))
    return lambda u: jax.block_until_ready(f(u, r, w, x0, g))


def _case(name, B, T, n, dtype, rng):
    u = np.cumsum(rng.normal(0.0, 0.1, (B, T)), axis=1).astype(dtype)
    r = np.linspace(0.0, 1.5, n).astype(dtype)
    w = rng.uniform(0.1, 1.0, n).astype(dtype)
    x0 = np.zeros(n, dtype)
    return u, r, w, x0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="experiments/results/bench_operators.json")
    ap.add_argument("--quick", action="store_true", help="small sizes, for a smoke test")
    ap.add_argument("--repeats", type=int, default=3, help="timed repeats per row (default 3)")
    ap.add_argument("--cases", default=None, help="comma-separated subset of " + ",".join(FULL))
    args = ap.parse_args(argv)

    sizes = QUICK if args.quick else FULL
    if args.cases:
        sizes = {k: sizes[k] for k in args.cases.split(",")}
    nb = _numba_loops()
    has_kernel, why = _kernel_status()
    skipped = []
    if nb is None:
        skipped.append("numba: not installed (pip install .[bench])")
    if not has_kernel:
        skipped.append(f"kernel: {why}")
    methods = ["jax_scan", "jax_associative"] + (["kernel"] if has_kernel else [])
    rng = np.random.default_rng(0)
    rows = []
    for case, (B, T, n) in sizes.items():
        for dtype in (np.float32, np.float64):
            u, r, w, x0 = _case(case, B, T, n, dtype, rng)
            ju = jnp.asarray(u)
            tol = 1e-3 if dtype == np.float32 else 1e-9
            for output in ("fused", "bank"):
                fused = output == "fused"
                # The NumPy loop is slow; one timed repeat is enough to see the scale.
                t_np, ref = _min_time(lambda: numpy_loop(u, r, w, x0, fused), 1)
                timings = {"numpy_loop": (t_np, ref)}
                if nb is not None:
                    timings["numba"] = _min_time(lambda: nb(u, r, w, x0, fused), args.repeats)
                grads = {}
                for m in methods:
                    f = _jax_fn(m.removeprefix("jax_"), fused, r, w, x0)
                    timings[m] = _min_time(lambda f=f: f(ju), args.repeats)
                    if fused and m in ("jax_scan", "kernel"):
                        g = rng.normal(size=u.shape).astype(dtype)
                        gf = _jax_grad_fn(m.removeprefix("jax_"), r, w, x0, g)
                        grads[m] = _min_time(lambda gf=gf: gf(ju), args.repeats)[0]
                elems = B * T * n
                for m, (sec, out) in timings.items():
                    dev = float(np.max(np.abs(np.asarray(out, np.float64) - ref)))
                    rows.append(
                        {
                            "case": case,
                            "signals": B,
                            "samples": T,
                            "plays": n,
                            "dtype": np.dtype(dtype).name,
                            "output": output,
                            "method": m,
                            "seconds": sec,
                            "elements_per_s": elems / sec,
                            "speedup_vs_numpy": t_np / sec,
                            "speedup_vs_numba": timings["numba"][0] / sec if nb else None,
                            "max_abs_dev_vs_numpy": dev,
                            "agrees": dev <= tol * (1 + float(np.max(np.abs(ref)))),
                            "grad_seconds": grads.get(m),
                            "grad_elements_per_s": elems / grads[m] if m in grads else None,
                            "grad_over_forward": grads[m] / sec if m in grads else None,
                        }
                    )
                    r_ = rows[-1]
                    print(
                        f"{case:10s} {r_['dtype']:7s} {output:5s} {m:15s} "
                        f"{r_['elements_per_s'] / 1e6:10.1f} M elem/s  "
                        f"x{r_['speedup_vs_numpy']:8.1f} vs NumPy"
                        + (f"  x{r_['speedup_vs_numba']:6.2f} vs Numba" if nb else "")
                        + (f"  grad {r_['grad_elements_per_s'] / 1e6:8.1f} M elem/s" if m in grads else ""),
                        flush=True,
                    )
    result = {
        "config": {
            "sizes": {k: {"signals": b, "samples": t, "plays": n} for k, (b, t, n) in sizes.items()},
            "quick": args.quick,
            "repeats": args.repeats,
            "timing": "min over repeats after a warm-up call, block_until_ready",
            "cpu_count": os.cpu_count(),
            "load_average_at_end": os.getloadavg(),
            "machine": platform.processor() or platform.machine(),
            "jax": jax.__version__,
            "backend": jax.default_backend(),
            "numba": None if nb is None else __import__("numba").__version__,
        },
        "skipped": skipped,
        "rows": rows,
    }
    os.makedirs(os.path.dirname(args.out) or ".", exist_ok=True)
    tmp = args.out + ".tmp"
    with open(tmp, "w") as f:
        json.dump(result, f, indent=2)
    os.replace(tmp, args.out)
    print(args.out)
    return 0 if all(r["agrees"] for r in rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())
