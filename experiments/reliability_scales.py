"""Extreme scales and long records, in float32 and float64.

1. Every estimator (ForgettingRLS, ContinuousRLS, NormalisedGradient) on a three-play record with
   u and y in units from 1e-6 to 1e6 (nine pairs, one vmapped call each): are the weights finite,
   and how far are they from the truth in the user's units, used as they are and with
   `estimate(..., rescale=True)` (H and y divided by their peaks, results in the user's units)?
2. `fit_pi` (thresholds, weights, offset) at the same scales: error in the user's units.
3. A 10⁶-sample record with u ~ 1e6 and y ~ 1e-6: CSV loading, the operator, two estimators;
   time, peak memory and the weight error.

Each precision runs in its own process (JAX fixes it at start). Writes
experiments/results/reliability_scales.json.
Run: python experiments/reliability_scales.py   (3 to 7 minutes on 2 cores)
"""

import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

OUT = Path(__file__).parent / "results" / "reliability_scales.json"
SCALES = [1e-6, 1.0, 1e6]
R = [0.0, 0.3, 0.6]
W = [1.0, 3.0, 5.0]
DT = 1e-3


def _peak_mb():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def run(precision: str) -> dict:
    import jax

    jax.config.update("jax_enable_x64", precision == "float64")
    import jax.numpy as jnp
    import numpy as np

    import piest_jax as pj
    from piest_jax import fit_pi, load_record

    dtype = jnp.float64 if precision == "float64" else jnp.float32
    pairs = [(su, sy) for su in SCALES for sy in SCALES]
    k = np.arange(20_000)
    u = np.sin(2 * np.pi * 5 * k * DT) * (1 + 0.5 * np.sin(2 * np.pi * 1.3 * k * DT))
    H = np.asarray(pj.PIOperator(np.array(R), np.array(W)).regressor(u), np.float64)
    y = H @ np.array(W)
    Hs = jnp.asarray(np.stack([H * su for su, _ in pairs]), dtype)
    ys = jnp.asarray(np.stack([y * sy for _, sy in pairs]), dtype)
    to_user = np.array([[su / sy] for su, sy in pairs])

    estimators = {
        "ForgettingRLS(P0=1e6)": pj.ForgettingRLS(1e6, 1.0),
        "ContinuousRLS(P0=1e6)": pj.ContinuousRLS(1e6, DT),
        "NormalisedGradient(1)": pj.NormalisedGradient(1.0),
    }
    scales = {}
    for name, est in estimators.items():

        def last(H, y, est=est, rescale=False):
            return pj.estimate(est, H, y, rescale=rescale).weights[-1]

        raw = np.asarray(jax.jit(jax.vmap(last))(Hs, ys), np.float64)
        normed = np.asarray(jax.jit(jax.vmap(lambda H, y: last(H, y, rescale=True)))(Hs, ys), np.float64)
        err = lambda w: (np.linalg.norm(w * to_user - W, axis=1) / np.linalg.norm(W)).tolist()  # noqa: E731
        scales[name] = {
            "pairs_su_sy": pairs,
            "finite_raw": bool(np.all(np.isfinite(raw))),
            "rel_error_raw": err(raw),
            "finite_normalised": bool(np.all(np.isfinite(normed))),
            "rel_error_normalised": err(normed),
        }

    kk = np.arange(400)
    uu = np.sin(2 * np.pi * kk / 100) * (1 + 0.4 * np.sin(2 * np.pi * kk / 430))
    yy = np.asarray(pj.PIOperator(np.array(R), np.array(W), initial_states=uu[0])(uu)) + 0.2
    fits = []
    for su, sy in pairs:
        f = fit_pi(su * uu, sy * yy, 3, n_starts=2, max_steps=80)
        th = np.asarray(f.thresholds, np.float64) / su
        w = np.asarray(f.weights, np.float64) * su / sy
        fits.append(
            {
                "su": su,
                "sy": sy,
                "result": f.result_name,
                "threshold_abs_error": float(np.max(np.abs(th - R))),
                "weight_rel_error": float(np.max(np.abs(w - W) / np.array(W))),
                "offset_error": abs(float(f.offset) / sy - 0.2),
                "finite": bool(np.all(np.isfinite(th)) and np.all(np.isfinite(w))),
            }
        )

    # The long record, written and read as CSV.
    n = 1_000_000
    kl = np.arange(n)
    ul = 1e6 * np.sin(2 * np.pi * kl / 1000) * (1 + 0.3 * np.sin(2 * np.pi * kl / 7919))
    r10, w10 = 1e6 * np.linspace(0.0, 0.9, 10), np.linspace(1.0, 0.1, 10) * 1e-12
    yl = np.asarray(pj.PIOperator(r10, w10 * 1e12, initial_states=ul[0])(ul), np.float64) * 1e-12
    long = {"n_samples": n}
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "long.csv"
        np.savetxt(p, np.column_stack([kl * 1e-4, ul, yl]), delimiter=",", fmt="%.17g", header="t,u,y", comments="")
        long["csv_mb"] = p.stat().st_size / 2**20
        t0 = time.perf_counter()
        rec = load_record(p)
        long["load_s"] = time.perf_counter() - t0
        long["peak_mb_after_load"] = _peak_mb()
    op = pj.PIOperator(jnp.asarray(r10, dtype), jnp.asarray(w10 * 1e12, dtype), initial_states=rec.u[0])
    t0 = time.perf_counter()
    Hl = op.regressor(jnp.asarray(rec.u, dtype))
    Hl.block_until_ready()
    long["regressor_s"] = time.perf_counter() - t0
    yl_d = jnp.asarray(rec.y, dtype)
    for name, est, rescale in [
        ("ForgettingRLS(P0=1e-4)", pj.ForgettingRLS(1e-4, 1.0), False),
        ("NormalisedGradient(1)", pj.NormalisedGradient(1.0), False),
        ("NormalisedGradient(1), rescale", pj.NormalisedGradient(1.0), True),
    ]:
        t0 = time.perf_counter()
        e = pj.estimate(est, Hl, yl_d, rescale=rescale)
        wl = np.asarray(e.weights[-1], np.float64)
        long[name] = {
            "seconds": time.perf_counter() - t0,
            "finite": bool(jnp.all(jnp.isfinite(e.weights))),
            "rel_error": float(np.linalg.norm(wl - w10) / np.linalg.norm(w10)),
        }
    long["peak_mb"] = _peak_mb()
    return {
        "precision": precision,
        "estimators_at_scales": scales,
        "fit_at_scales": fits,
        "long_record": long,
        "devices": [str(d) for d in jax.devices()],
    }


def main():
    if len(sys.argv) > 1 and sys.argv[1] in ("float32", "float64"):
        print(json.dumps(run(sys.argv[1])))
        return
    results = {}
    for precision in ("float32", "float64"):
        proc = subprocess.run([sys.executable, __file__, precision], capture_output=True, text=True)
        if proc.returncode:
            sys.exit(proc.stderr)
        results[precision] = json.loads(proc.stdout.strip().splitlines()[-1])
        print(precision, json.dumps(results[precision]["long_record"]))
    import piest_jax as pj

    print(pj.write_json(OUT, results))


if __name__ == "__main__":
    main()
