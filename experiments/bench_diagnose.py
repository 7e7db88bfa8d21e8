"""Wall time of `piest diagnose` on a 10^4-sample record (compilation included), as JSON.

python experiments/bench_diagnose.py   ->  experiments/results/bench_diagnose.json
"""

import json
import os
import tempfile
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import piest_jax as pj  # noqa: E402


def run():
    rec, truth = pj.hidden_effect_record(("creep",), key=jax.random.PRNGKey(0), n_samples=10_000)
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "rec.csv"
        p.write_text("t,u,y\n" + "\n".join(f"{a:.17g},{b:.17g},{c:.17g}" for a, b, c in zip(rec.t, rec.u, rec.y)))
        t0 = time.perf_counter()
        rc = pj.run_cli(["diagnose", str(p), "--out", str(Path(d) / "out"), "--quiet"])
        secs = time.perf_counter() - t0
        rep = json.loads((Path(d) / "out" / "report.json").read_text())
    res = dict(
        n_samples=10_000,
        seconds=secs,
        rc=rc,
        cpus=os.cpu_count(),
        load_average=os.getloadavg(),
        effects=rep["effects"],
        hidden=truth["effects"],
        note="one process, compilation included",
    )
    out = Path(__file__).parent / "results" / "bench_diagnose.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(res, indent=1))
    print(json.dumps(res))


if __name__ == "__main__":
    run()
