"""Wall time of `piest fit` with each --model on a 10^4-sample record (compilation included),
and the Aye & Ang validation numbers of each, as JSON.

    python experiments/bench_fit_models.py   ->  experiments/results/bench_fit_models.json
    python experiments/bench_fit_models.py --models pi+creep   (re-runs one model, keeps the rest)

The timed record is the hidden-effect generator's creep record (10^4 samples); the Aye pair is
identified on the identification run and scored on the validation run, nothing fitted on it.
"""

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import piest_jax as pj  # noqa: E402

DATA = Path(__file__).parents[1] / "piest_jax" / "data"
MODELS = ("auto", "pi", "pi+creep")


def _fit(args, d, name):
    out = Path(d) / name
    t0 = time.perf_counter()
    rc = pj.run_cli(["fit", *args, "--out", str(out), "--quiet", "--force"])
    secs = time.perf_counter() - t0
    rep = json.loads((out / "fit.json").read_text()) if rc == 0 else {}
    keep = ("model", "rmse", "validation_rmse", "validation_rmse_ic", "validation_fit_percent")
    return dict(
        seconds=secs,
        rc=rc,
        **{k: rep.get(k) for k in keep},
        time_constants=(rep.get("creep") or {}).get("time_constants"),
    )


def run(models=MODELS):
    rec, truth = pj.hidden_effect_record(("creep",), key=jax.random.PRNGKey(0), n_samples=10_000)
    out = Path(__file__).parent / "results" / "bench_fit_models.json"
    old = json.loads(out.read_text()) if out.exists() and tuple(models) != MODELS else {}
    res = {
        "cpus": os.cpu_count(),
        "note": "one process per run, compilation included",
        **{k: old[k] for k in ("load_average",) if k in old},
    }
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "rec.csv"
        p.write_text("t,u,y\n" + "\n".join(f"{a:.17g},{b:.17g},{c:.17g}" for a, b, c in zip(rec.t, rec.u, rec.y)))
        res["synthetic_1e4"] = {
            **old.get("synthetic_1e4", {}),
            **{m: _fit([str(p), "--model", m], d, f"s-{m}") for m in models},
        }
        ident = DATA / "piezo_aye2018_identification.csv"
        val = DATA / "piezo_aye2018_validation.csv"
        res["aye"] = {
            **old.get("aye", {}),
            **{m: _fit([str(ident), "--validate", str(val), "--model", m], d, f"a-{m}") for m in models},
        }
    # The machine's load averages when each model's runs ended (a re-run model gets its own).
    res["load_average_by_model"] = {**old.get("load_average_by_model", {}), **{m: os.getloadavg() for m in models}}
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(res, indent=1))
    print(json.dumps(res, indent=1))


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--models", default=",".join(MODELS), help=f"comma-separated models to run (default all: {','.join(MODELS)})"
    )
    run(tuple(ap.parse_args().models.split(",")))
