"""`piest excite`: design an input that excites a play bank with the largest guaranteed margin."""

import numpy as np

from .._excitation.design import design_input
from .._excitation.design_compare import excitation_figure, excitation_report
from . import memory
from . import output as _io
from ._common import CLIError, add_output_options, float_list, positive_float, positive_int

NAME = "excite"
DESCRIPTION = """\
Design an input of --samples samples for the plays --thresholds that stays within +-amplitude,
moves no faster than a sine of --frequency at that amplitude (slew 2 pi f A), and maximises the
smallest guaranteed PE margin over windows of --window samples: a lower bound on the PE level c1
from the input's swings between events (docs/excitation_condition.md, Theorem 4), which bounds
how fast the paper's RLS converges (Corollary 5). The input rises from -A by half-cycles that
start each play in turn; how much of each period goes to each swing solves a concave problem.
The design is then compared with the sine: the paper's RLS (P0 I, data rescaled to magnitude
one) estimates --weights from each input's noise-free output. Its default P0 is moderate: with a
large P0 any input of full rank converges within a few samples, which hides what the margin
measures. Writes
  DIR/excite.csv   t, u: the designed input
  DIR/excite.json  settings, plan (the swing levels, pairs per period, period, shares),
                   and for the design and the sine: margin, pe_level, exact_condition_holds,
                   time_to_1pct (s; null and inf under non_finite: it does not stay below 1 %),
                   final_error, and both for the worst weight vector (time_to_1pct_worst,
                   final_error_worst: what the margin bounds); margin_ratio (design/sine;
                   inf when only the design is PE in every window)
  DIR/excite.png   both inputs, the RLS weight error over time, the margin per window

example:  piest excite --thresholds 0,3.33,6.67 --amplitude 10 --samples 1000 --out design"""

OUTPUTS = ("excite.csv", "excite.json", "excite.png")
NONFINITE = ("time_to_1pct", "time_to_1pct_worst", "margin_ratio")


def add_arguments(p):
    p.add_argument(
        "--thresholds",
        type=float_list,
        required=True,
        metavar="R1,R2,...",
        help="play thresholds, >= 0 and strictly increasing",
    )
    p.add_argument("--samples", type=positive_int, required=True, help="samples of the input")
    p.add_argument(
        "--amplitude", type=positive_float, help="limit A on |u|, above the largest threshold (default 2 r_max)"
    )
    p.add_argument("--dt", type=positive_float, default=1e-3, help="sampling step in s (default 1e-3)")
    p.add_argument(
        "--frequency",
        type=positive_float,
        help="frequency of the comparison sine, which sets the slew limit 2 pi f A "
        "(default: 10 periods over the record)",
    )
    p.add_argument("--window", type=positive_int, help="PE window in samples (default samples // 5)")
    p.add_argument(
        "--weights", type=float_list, metavar="W1,W2,...", help="true weights for the RLS comparison (default all 1)"
    )
    p.add_argument(
        "--P0",
        type=positive_float,
        default=1e3,
        help="RLS initial gain P0 I, for data scaled to magnitude one (default 1e3)",
    )
    add_output_options(p, "piest-excite")


def _settings(args):
    r = np.asarray(args.thresholds, float)
    if r[0] < 0 or np.any(np.diff(r) <= 0):
        raise CLIError("--thresholds must be >= 0 and increase strictly, e.g. 0,1,2")
    if args.amplitude is None and r[-1] == 0:
        raise CLIError("give --amplitude: its default, twice the largest threshold, is 0 here")
    amplitude = 2 * float(r[-1]) if args.amplitude is None else args.amplitude
    if amplitude <= r[-1]:
        raise CLIError(f"--amplitude ({amplitude:g}) must exceed the largest threshold ({r[-1]:g})")
    if args.window is None and args.samples < 10:
        raise CLIError(
            f"--samples {args.samples} is too short for the default window (samples // 5, "
            "at least 2): give at least 10, or --window"
        )
    window = args.samples // 5 if args.window is None else args.window
    if not 2 <= window <= args.samples:
        raise CLIError(f"--window ({window} samples) must be between 2 and --samples ({args.samples})")
    frequency = 10 / (args.samples * args.dt) if args.frequency is None else args.frequency
    if frequency * args.dt >= 0.5:
        raise CLIError(
            f"--frequency {frequency:g} Hz is at or above the Nyquist frequency "
            f"{0.5 / args.dt:g} Hz of --dt {args.dt:g}"
        )
    weights = np.ones_like(r) if args.weights is None else np.asarray(args.weights, float)
    if weights.shape != r.shape:
        raise CLIError(f"--weights has {weights.size} values for {r.size} thresholds")
    if not np.any(weights != 0):
        raise CLIError("--weights must not all be 0 (the error is relative to them)")
    return r, amplitude, window, frequency, weights


def run(args) -> int:
    r, amplitude, window, frequency, weights = _settings(args)
    memory.require(
        memory.rls_bytes(r.size, args.samples) + 2 * memory.bank_bytes(args.samples, r.size),
        f"--samples {args.samples} with {r.size} thresholds",
        "use fewer samples",
    )
    out = _io.check_outputs(args.out, OUTPUTS, args.force)
    slew = 2 * np.pi * frequency * amplitude
    try:
        design = design_input(r, amplitude=amplitude, n_samples=args.samples, window=window, dt=args.dt, slew=slew)
    except ValueError as e:
        raise CLIError(str(e).replace("`window`", "--window").replace("`amplitude`", "--amplitude")) from None
    t = np.arange(args.samples) * args.dt
    inputs = {"design": design.u, "sine": amplitude * np.sin(2 * np.pi * frequency * t)}
    reports = {k: excitation_report(u, r, weights, dt=args.dt, window=window, P0=args.P0) for k, u in inputs.items()}
    summary = {
        k: {key: v for key, v in rep.items() if key not in ("error", "margins", "worst_k", "worst_error")}
        for k, rep in reports.items()
    }
    sine_margin = reports["sine"]["margin"]
    report = dict(
        thresholds=r,
        amplitude=amplitude,
        samples=args.samples,
        dt=args.dt,
        window=window,
        frequency=frequency,
        slew=slew,
        weights=weights,
        P0=args.P0,
        plan=dict(
            levels=design.levels,
            pairs_per_period=design.pairs,
            period=design.period,
            shares=design.shares,
            ideal_margin=design.ideal_margin,
        ),
        **summary,
        # inf when only the design is PE in every window; NaN when neither is.
        margin_ratio=np.divide(reports["design"]["margin"], sine_margin)
        if sine_margin > 0
        else (np.inf if reports["design"]["margin"] > 0 else np.nan),
    )
    written = [_io.write_csv(out / "excite.csv", {"t": t, "u": design.u})]
    written.append(_io.write_json(out / "excite.json", report))
    fig = excitation_figure(inputs, reports, dt=args.dt, window=window)
    written.append(_io.save_figure(fig, out / "excite.png", dpi=110))
    print("\n".join(str(p) for p in written))
    return 0
