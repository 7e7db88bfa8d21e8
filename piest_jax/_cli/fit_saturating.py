"""`piest fit --model gpi` and `--model preisach`: the models that saturate.

Their options (`--terms`; `--grid`, `--smoothness`) and their files; `identify` fits them and
refuses the options they would ignore (`fit.py` checks the options and calls `run`).
"""

import argparse
import sys

import numpy as np

from .._identification import identify_saturating
from .._identification.band import prediction_band
from .._identification.covariance import table as parameter_table
from .._identification.fit_gpi import GPIFit
from .._identification.fit_preisach import PreisachFit
from .._identification.identify import identify
from . import memory
from . import output as _io
from ._common import CLIError, note_extrapolation, note_loop, positive_int, record_fields

TERMS, GRID = identify_saturating.TERMS, identify_saturating.GRID


_REMEDY = {
    "gpi": "try fewer plays or terms, or a record that reaches further into saturation",
    "preisach": "the input never switches those relays apart; try a coarser --grid, or a "
    "record that covers the input range with reversals of every size",
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
    p.add_argument(
        "--terms",
        type=positive_int,
        default=None,
        metavar="K",
        help=f"--model gpi: tanh terms of the output function (default {TERMS})",
    )
    p.add_argument(
        "--grid",
        type=grid_arg,
        default=None,
        metavar="K,M",
        help=f"--model preisach: half-widths and centres of the relay grid (default {GRID[0]},{GRID[1]})",
    )
    p.add_argument(
        "--smoothness",
        type=float,
        default=None,
        metavar="S",
        help="--model preisach: the density's smoothness penalty (default: chosen on held-out blocks of the record)",
    )


def run(args, rec, val, out, options: dict) -> int:
    """Fit the model (`identify` with `options`), then write fit.json, fit.md, fit.png (and
    validation.png)."""
    import jax

    if args.model == "gpi":
        terms = TERMS if args.terms is None else args.terms
        n_params = 2 * args.plays + 3 * terms
        memory.require(
            memory.fit_bytes(rec.n_samples, args.starts, n_params),
            f"--starts {args.starts} on {args.data} ({rec.n_samples} samples, {n_params} parameters)",
            "use fewer --starts, fewer plays or a shorter record",
        )
    try:
        result = identify(rec, val, **options, fit_from=args.fit_from, key=jax.random.key(args.seed))
    except ValueError as e:
        raise CLIError(f"{args.data}: {' '.join(str(e).split())}") from None
    note_loop(args, result.loop, result.positive_weights)
    return write(args, result, out)


def write(args, result, out) -> int:
    """Write fit.json, fit.md, fit.png (and validation.png) for a model that saturates, whether
    asked for (`--model gpi|preisach`) or chosen by `--model auto`."""
    from .._identification.figures import fit_figure

    assert isinstance(result.fit, GPIFit | PreisachFit)
    rec, val = result.record, None if result.validation is None else result.validation.record
    report = {**result.to_json(), **record_fields(rec, args)}
    note_extrapolation(args, report)
    table = "" if result.fit.std_errors is None else parameter_table(result.fit)
    written = [
        _io.write_json(out / "fit.json", report),
        _io.write_text(out / "fit.md", _markdown(args, report, table)),
        _io.save_figure(
            fit_figure(
                rec, np.asarray(result.fit.model(rec.u)), title="fit", mask=result.mask, band=_band(result.fit, rec.u)
            ),
            out / "fit.png",
            dpi=110,
        ),
    ]
    v = result.validation
    if v is not None:
        band = None if v.raw_band is None else v.raw_band.interval()
        written.append(
            _io.save_figure(
                fit_figure(val, np.asarray(v.raw.prediction), title="validation", band=band),
                out / "validation.png",
                dpi=110,
            )
        )
    undetermined = report.get("undetermined") or []
    if undetermined:
        print(
            f"piest fit: warning: the record does not determine {', '.join(undetermined)} "
            "(standard error beyond half the parameter's scale, or free in the Jacobian's "
            f"rank); predictions that depend on them are arbitrary: {_REMEDY[report['structure']]}",
            file=sys.stderr,
        )
    for p in written:
        print(p)
    return 0


def _band(fit, u):
    """The 95 % measurement band of the fit on `u`, or None without a covariance."""
    if fit.covariance is None:
        return None
    return prediction_band(fit, u).interval()


def _chosen(report, structure) -> list[str]:
    """fit.md's lines on why `--model auto` chose this model (none when it was asked for)."""
    chosen = report.get("selection", {}).get(structure)
    if chosen is None:
        return []
    why = ""
    if structure == "gpi":
        gate = f"{chosen['gate']:.2g}"
        why = f"the output saturates (a saturating function of a 16-play PI's output leaves {gate} of its error); "
    best_pi = min(m["score"] for m in report["selection"]["models"] if not m["rejected"])
    return [
        "",
        f"Chosen by --model auto: {why}held-out RMSE {chosen['score']:.4g} against the best PI "
        f"candidate's {best_pi:.4g}, every parameter determined by the record.",
    ]


def _markdown(args, report, table="") -> str:
    lines = [f"# piest fit: {args.data}", ""]
    if report["structure"] == "gpi":
        g = report["output_function"]
        lines += [
            f"gpi, {report['n_plays']} plays, {len(g['amplitudes'])} tanh terms; RMSE {report['rmse']:.4g}.",
            "",
            "y = offset + sum_k a_k tanh((v - c_k)/s_k), v = sum_j w_j H_{r_j}[u]",
            "",
            "| play | threshold | weight |",
            "|---|---|---|",
        ]
        lines += [
            f"| {j + 1} | {r:.6g} | {w:.6g} |" for j, (r, w) in enumerate(zip(report["thresholds"], report["weights"]))
        ]
        lines += ["", "| term | amplitude | centre | scale |", "|---|---|---|---|"]
        lines += [
            f"| {k + 1} | {a:.6g} | {c:.6g} | {s:.6g} |"
            for k, (a, c, s) in enumerate(zip(g["amplitudes"], g["centres"], g["scales"]))
        ]
        lines += _chosen(report, "gpi")
        if table:
            method = report["covariance"]["method"]
            lines += ["", f"Standard errors ({method}):", "", table.rstrip("\n")]
    else:
        K, M = report["grid"]
        lines += [
            f"preisach, {K} x {M} grid ({'non-negative' if report['model']['monotone'] else 'signed'}"
            f" density), smoothness {report['smoothness']:.3g}; RMSE {report['rmse']:.4g}.",
            "",
            "The density is in fit.json (`density`, half-widths by centres).",
        ]
        lines += _chosen(report, "preisach")
        if "std_errors" in report:
            bad = report["undetermined"]
            lines += [
                "",
                f"Its standard errors ({report['covariance']['method']}, at this "
                "smoothness) are in fit.json (`std_errors`, `covariance`); "
                f"{len(bad)} of its {len(report['std_errors'])} parameters are not "
                "determined by the record" + (f": {', '.join(bad)}." if bad else "."),
            ]
    lines += ["", f"offset {float(report['offset']):.6g}", ""]
    print("\n".join(lines[2:]), file=sys.stderr)
    return "\n".join(lines)
