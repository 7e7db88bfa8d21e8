"""`piest fit --model gpi` and `--model preisach`: the models that saturate.

Kept apart from the PI and PI + creep path of `fit.py`, which calls `refuse_ignored` before its
own checks and `run` once the records are read: these models have their own options (`--terms`;
`--grid`, `--smoothness`), write the same files, and refuse the options they would ignore.
"""

import argparse
import sys

import numpy as np

from .._identification.fit_gpi import fit_gpi
from .._identification.fit_preisach import fit_preisach
from .._identification.identify import input_extent
from .._identification.model_file import model_keys
from . import memory
from . import output as _io
from ._common import CLIError, positive_int, record_fields

MODELS = ("gpi", "preisach")
TERMS = 2  # fit_gpi's default: one term fixes the knee's shape, a second frees it
GRID = (16, 16)  # half-widths x centres: the input range resolved in sixteenths, as a 16-play PI

# Options of the PI path, with their defaults: a value other than the default is refused by a
# model that does not use it. `None` defaults are "not given".
_PI_ONLY = {"lags": None, "time_constants": None, "candidates": None, "criterion": None}
_BY_MODEL = {
    "gpi": {**_PI_ONLY, "signed_weights": False, "grid": None, "smoothness": None},
    "preisach": {**_PI_ONLY, "plays": "auto", "solver": "lm", "seed": 0, "starts": 4,
                 "fit_initial_states": False, "max_threshold": None, "max_steps": 100,
                 "terms": None},
}


def grid_arg(text: str) -> tuple[int, int]:
    parts = text.split(",")
    try:
        if len(parts) != 2:
            raise argparse.ArgumentTypeError("two numbers")
        return positive_int(parts[0].strip()), positive_int(parts[1].strip())
    except argparse.ArgumentTypeError as e:
        raise argparse.ArgumentTypeError(f"expected half-widths,centres like 16,16: {e}") from None


def add_arguments(p) -> None:
    """The options of these models (the others are the PI path's, shared where they apply)."""
    p.add_argument("--terms", type=positive_int, default=None, metavar="K",
                   help=f"--model gpi: tanh terms of the output function (default {TERMS})")
    p.add_argument("--grid", type=grid_arg, default=None, metavar="K,M",
                   help=f"--model preisach: half-widths and centres of the relay grid "
                   f"(default {GRID[0]},{GRID[1]})")
    p.add_argument("--smoothness", type=float, default=None, metavar="S",
                   help="--model preisach: the density's smoothness penalty (default: chosen "
                   "on held-out blocks of the record)")


def refuse_ignored(args) -> None:
    """One line (CLIError) for an option the chosen model would ignore; --terms, --grid and
    --smoothness are refused by the PI models."""
    if args.model not in MODELS:
        for name, value in (("--terms", args.terms), ("--grid", args.grid),
                            ("--smoothness", args.smoothness)):
            if value is not None:
                model = "gpi" if name == "--terms" else "preisach"
                raise CLIError(f"{name} is used only by --model {model}, not --model {args.model}")
        return
    for dest, default in _BY_MODEL[args.model].items():
        if getattr(args, dest) != default:
            option = "--" + dest.replace("_", "-")
            raise CLIError(f"{option} does not apply to --model {args.model}; leave it out")
    if args.model == "gpi" and args.plays == "auto":
        raise CLIError("--model gpi needs --plays N: its number of plays is not chosen "
                       "automatically")
    if args.smoothness is not None and not (np.isfinite(args.smoothness) and args.smoothness >= 0):
        raise CLIError(f"--smoothness must be finite and >= 0, got {args.smoothness:g}")


def run(args, rec, val, mask, out) -> int:
    """Fit the model, then write fit.json, fit.md, fit.png (and validation.png)."""
    import jax

    from .._identification.figures import fit_figure

    if args.model == "gpi":
        terms = TERMS if args.terms is None else args.terms
        n_params = 2 * args.plays + 3 * terms
        memory.require(
            memory.fit_bytes(rec.n_samples, args.starts, n_params),
            f"--starts {args.starts} on {args.data} ({rec.n_samples} samples, {n_params} "
            "parameters)", "use fewer --starts, fewer plays or a shorter record")
        try:
            f = fit_gpi(rec.u, rec.y, args.plays, n_terms=terms, mask=mask, solver=args.solver,
                        n_starts=args.starts, key=jax.random.key(args.seed),
                        fit_initial_states=args.fit_initial_states,
                        initial_states=args.initial_states, max_threshold=args.max_threshold,
                        max_steps=args.max_steps)
        except ValueError as e:
            raise CLIError(f"{args.data}: {' '.join(str(e).split())}") from None
        model, rmse = f.model, float(f.rmse)
        details = {
            "model": {"structure": "gpi", "n_plays": model.n_plays, "n_terms": model.n_terms},
            "n_plays": model.n_plays,
            "solver": {"name": args.solver, "result": f.result_name, "steps": f.n_steps,
                       "start_rmse": f.start_rmse},
        }
    else:
        K, M = GRID if args.grid is None else args.grid
        try:
            f = fit_preisach(rec.u, rec.y, n_widths=K, n_centres=M, smoothness=args.smoothness,
                             mask=mask, initial_states=args.initial_states,
                             monotone=not args.signed_weights)
        except ValueError as e:
            raise CLIError(f"{args.data}: {' '.join(str(e).split())}") from None
        model, rmse = f.model, f.rmse
        details = {
            "model": {"structure": "preisach", "grid": [K, M],
                      "monotone": not args.signed_weights},
            "grid": [K, M],
            "smoothness": f.smoothness,
            "smoothness_candidates": list(f.candidates),
            "held_out_rmse": list(f.held_out_rmse),
            "n_blocks": f.n_blocks,
        }
    report = {
        **model_keys(model),
        "data": str(args.data),
        "n_samples": rec.n_samples,
        "dt": rec.dt,
        **record_fields(rec, args),
        **details,
        "rmse": rmse,
        **input_extent(rec, mask),
    }
    if args.fit_from is not None:
        report["fit_from"] = args.fit_from
    written = []
    if val is not None:
        m = _validation_model(args, model, val)
        yv = np.asarray(m(val.u))
        report["validate"] = str(args.validate)
        report["validation_initial_states"] = (
            "first input" if args.initial_states is None and not args.fit_initial_states
            else "given" if args.initial_states is not None else "fitted")
        report["validation_rmse"] = float(np.sqrt(np.mean((yv - val.y) ** 2)))
        written.append(_io.save_figure(fit_figure(val, yv, title="validation"), out / "validation.png",
                                       dpi=110))
    ym = np.asarray(model(rec.u))
    written.insert(0, _io.save_figure(fit_figure(rec, ym, title="fit", mask=mask), out / "fit.png",
                                      dpi=110))
    written.insert(0, _io.write_text(out / "fit.md", _markdown(args, report)))
    written.insert(0, _io.write_json(out / "fit.json", report))
    for p in written:
        print(p)
    return 0


def _validation_model(args, model, val):
    """The model on the validation record: plays at its first input unless states were given
    or fitted (a Preisach model with no states given starts at its record's first input)."""
    if args.model == "gpi":
        if args.fit_initial_states:
            return model
        return model.with_initial_states(val.u[0] if args.initial_states is None
                                         else args.initial_states)
    return model


def _markdown(args, report) -> str:
    lines = [f"# piest fit: {args.data}", ""]
    if args.model == "gpi":
        g = report["output_function"]
        lines += [f"gpi, {report['n_plays']} plays, {len(g['amplitudes'])} tanh terms; RMSE "
                  f"{report['rmse']:.4g}.", "",
                  "y = offset + sum_k a_k tanh((v - c_k)/s_k), v = sum_j w_j H_{r_j}[u]", "",
                  "| play | threshold | weight |", "|---|---|---|"]
        lines += [f"| {j + 1} | {r:.6g} | {w:.6g} |"
                  for j, (r, w) in enumerate(zip(report["thresholds"], report["weights"]))]
        lines += ["", "| term | amplitude | centre | scale |", "|---|---|---|---|"]
        lines += [f"| {k + 1} | {a:.6g} | {c:.6g} | {s:.6g} |"
                  for k, (a, c, s) in enumerate(zip(g["amplitudes"], g["centres"], g["scales"]))]
    else:
        K, M = report["grid"]
        lines += [f"preisach, {K} x {M} grid ({'non-negative' if report['model']['monotone'] else 'signed'}"
                  f" density), smoothness {report['smoothness']:.3g}; RMSE {report['rmse']:.4g}.",
                  "", "The density is in fit.json (`density`, half-widths by centres)."]
    lines += ["", f"offset {float(report['offset']):.6g}", ""]
    print("\n".join(lines[2:]), file=sys.stderr)
    return "\n".join(lines)
