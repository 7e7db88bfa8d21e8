"""The paper's Figs. 5 and 6 and the measurement-noise study, into experiments/results/paper/.

Figs. 5 and 6 are the same code as `piest reproduce` (`piest_jax.paper`); `noise` is the
batch Monte Carlo study of `piest_jax.paper.noise_study` (bias and spread of the final estimate
against the noise level, and the forgetting-factor trade-off after a weight jump).

    python experiments/reproduce_paper.py                 # fig5, fig6 and noise
    python experiments/reproduce_paper.py fig5 --P0 1e9   # one figure, another P0
"""

import argparse
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import piest_jax as pj  # noqa: E402
from piest_jax import paper  # noqa: E402

DEFAULT_OUT = Path(__file__).resolve().parent / "results" / "paper"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    choices = [*paper.FIGURES, "noise"]
    p.add_argument("what", nargs="*", help=f"any of {choices} (default: all)")
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, help="output folder")
    p.add_argument("--P0", type=float, default=paper.DEFAULT_P0, help="initial gain P0*I")
    p.add_argument("--normalisation", choices=["paper", "standard"], default="paper")
    p.add_argument("--replicates", type=int, default=64, help="noise draws per setting")
    p.add_argument("--seed", type=int, default=0, help="PRNG seed of the noise study")
    args = p.parse_args(argv)
    what = args.what or choices
    if any(w not in choices for w in what):
        p.error(f"choose from {choices}, got {what}")
    args.out.mkdir(parents=True, exist_ok=True)
    for name in what:
        t0 = time.perf_counter()
        if name == "noise":
            key = jax.random.PRNGKey(args.seed)
            report = paper.noise_study(key=key, replicates=args.replicates)
            report["seed"] = args.seed
            fig = paper.noise_figure(report)
        else:
            full = paper.reproduce(name, P0=args.P0, normalisation=args.normalisation)
            fig, report = paper.figure(full), paper.public_report(full)
        report["runtime_s"] = time.perf_counter() - t0
        print(pj.save_figure(fig, args.out / f"{name}.png", dpi=120))
        print(pj.write_json(args.out / f"{name}.json", report))
    return 0


if __name__ == "__main__":
    sys.exit(main())
