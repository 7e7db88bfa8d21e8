"""`piest reproduce`: the paper's Figs. 5 and 6 (continuous-time RLS on a three-play PI operator)."""

from .._estimation.reproduce import DEFAULT_P0, FIGURES, figure, public_report, reproduce
from . import output as _io
from ._common import add_output_options, positive_float

NAME = "reproduce"
DESCRIPTION = f"""\
Run the paper's continuous-time RLS (eqs. 5-6, integrated exactly in information form) on its two
simulation settings, thresholds (0, 10/3, 20/3), dt = 1 ms, t in [0, 1] s, W(0) = 0:
  fig5  u = 10 sin(2 pi 5 t), weights (1, 3, 5)
  fig6  u = 10 sin(10 pi t) + 5 sin(2 pi t), weights (2, 6, 8)
and write, for each figure asked for,
  DIR/figN.png   weight errors over time (as in the paper) and convergence time against P0
  DIR/figN.json  weights_true, weights_final, final_abs_error, time_to_1pct (first time after
                 which every weight stays within 1 %), P0, estimator, PE level, certificate
The default P0 = {DEFAULT_P0:.0e}·I converges within 1 % in about 0.03 s; the second panel
shows the time to 1 % for P0 from 1e2 to 1e12 under both normalisations.

example:  piest reproduce all --out results/paper"""

# A time that is never reached within the record is infinite (null in the JSON, listed under
# "non_finite"); any other non-finite result fails the command.
NONFINITE = ("time_to_1pct", "time_input_exceeds_r_max")


def add_arguments(p):
    p.add_argument("figure", choices=[*FIGURES, "all"], help="which figure (or all)")
    p.add_argument(
        "--P0", type=positive_float, default=DEFAULT_P0, help=f"initial gain P0·I (default {DEFAULT_P0:.0e})"
    )
    p.add_argument(
        "--normalisation",
        choices=["paper", "standard"],
        default="paper",
        help="paper: m = 1 + h'h, divide by m^2 (default); standard: m^2 = 1 + h'h",
    )
    add_output_options(p, "piest-reproduce")


def run(args) -> int:
    names = FIGURES if args.figure == "all" else (args.figure,)
    outputs = [f"{n}.{ext}" for n in names for ext in ("png", "json")]
    out = _io.check_outputs(args.out, outputs, args.force)
    for n in names:
        report = reproduce(n, P0=args.P0, normalisation=args.normalisation)
        print(_io.save_figure(figure(report), out / f"{n}.png", dpi=120))
        print(_io.write_json(out / f"{n}.json", public_report(report)))
    return 0
