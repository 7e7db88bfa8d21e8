"""`piest simulate`: run a PI operator on a described input and write a CSV and a loop plot."""

import numpy as np

from .._excitation import signals as _signals
from .._operators.figure import loop_figure
from .._operators.pi import PIOperator
from . import memory
from . import output as _io
from ._common import (
    CLIError,
    add_output_options,
    add_record_options,
    check_creep_sampling,
    finite_float,
    float_list,
    positive_float,
    positive_int,
    read_record,
    record_fields,
)

NAME = "simulate"
DESCRIPTION = """\
Run a Prandtl-Ishlinskii operator y = sum_j w_j H_{r_j}[u] on an input and write
  DIR/simulate.csv   columns t, u, y and the play outputs x_1..x_n
  DIR/loop.png       the y-u loop and the play outputs over time
  DIR/simulate.json  the operator, the input description and summary numbers
The defaults are the paper's Fig. 5 setting: u = 10 sin(2 pi 5 t), t in [0, 1] s, dt = 1 ms,
thresholds (0, 10/3, 20/3), weights (1, 3, 5). --model MODEL.json runs the model in a model
file (`piest fit`'s fit.json, `piest diagnose`'s model.json, `save_model`'s) instead, from its
own states; simulate.csv then holds its plays' outputs.

example:  piest simulate --input triangle --amplitude 5 --thresholds 0,1,2,3 --out sim"""

OUTPUTS = ("simulate.csv", "loop.png", "simulate.json")
MAX_SAMPLES = 10_000_000
MAX_VALUES = 50_000_000  # samples x plays in the CSV (about 1 GB of text)


def add_arguments(p):
    p.add_argument(
        "--input",
        choices=["sine", "multisine", "triangle", "chirp", "csv"],
        default="sine",
        help="input shape (default: sine); 'csv' takes t and u from --csv",
    )
    p.add_argument("--csv", metavar="FILE", help="data file whose t and u columns are the input")
    p.add_argument(
        "--amplitude", type=float_list, default=None, help="amplitude(s); several for multisine (default 10)"
    )
    p.add_argument("--frequency", type=float_list, default=None, help="frequency/ies in Hz (default 5)")
    p.add_argument("--offset", type=finite_float, default=None, help="constant added to the input (default 0)")
    p.add_argument("--duration", type=positive_float, default=None, help="seconds (default 1)")
    p.add_argument("--dt", type=positive_float, default=None, help="sampling step (default 1e-3)")
    p.add_argument(
        "--thresholds",
        type=float_list,
        default=None,
        help="comma-separated thresholds, increasing from 0 (default 0,3.3333,6.6667)",
    )
    p.add_argument("--plays", type=positive_int, help="instead of --thresholds: N thresholds uniform on [0, r_max)")
    p.add_argument("--r-max", type=positive_float, help="largest threshold scale with --plays")
    p.add_argument("--weights", type=float_list, help="comma-separated weights (default 1,3,5)")
    p.add_argument(
        "--initial-states",
        type=float_list,
        default=None,
        help="the plays' initial states: one value for all, or one per play (default 0)",
    )
    p.add_argument("--model", metavar="MODEL.json", help="run the model in this model file instead of a PI operator")
    add_record_options(p)
    add_output_options(p, "piest-simulate")


# The described input's settings: a CSV input has its own, so giving them there is refused.
SHAPE_DEFAULTS = {"amplitude": [10.0], "frequency": [5.0], "offset": 0.0, "duration": 1.0, "dt": 1e-3}


def _input(args):
    if args.input == "csv":
        if not args.csv:
            raise CLIError("--input csv needs --csv FILE")
        for name in SHAPE_DEFAULTS:
            if getattr(args, name) is not None:
                raise CLIError(f"--{name} describes a generated input; --input csv takes t and u from {args.csv}")
        rec = read_record(args.csv, args)
        return rec.t, rec.u, {"kind": "csv", "file": str(args.csv), **record_fields(rec, args)}
    for given, name in (
        (args.csv, "--csv"),
        (args.columns, "--columns"),
        (args.resample, "--resample"),
        (args.max_gap is not None, "--max-gap"),
        (args.segment is not None, "--segment"),
    ):
        if given:
            raise CLIError(f"{name} is only used with --input csv, not --input {args.input}")
    for name, value in SHAPE_DEFAULTS.items():
        if getattr(args, name) is None:
            setattr(args, name, value)
    n = args.duration / args.dt + 1
    if n < 2:
        raise CLIError(f"--dt {args.dt:g} is longer than --duration {args.duration:g}: no signal")
    if n > MAX_SAMPLES:
        raise CLIError(
            f"--duration {args.duration:g} / --dt {args.dt:g} gives {n:.3g} samples; at most "
            f"{MAX_SAMPLES:.0e} are written (raise --dt or shorten --duration)"
        )
    t = np.asarray(_signals.time_grid(args.duration, args.dt))
    a, f = args.amplitude, args.frequency
    _check_frequencies(f, args.dt)
    if args.input == "multisine":
        if len(a) != len(f):
            raise CLIError(f"multisine: {len(a)} amplitudes but {len(f)} frequencies")
        u = _signals.multisine(t, a, f, offset=args.offset)
    else:
        if len(a) != 1 or len(f) != 1:
            raise CLIError(f"--input {args.input} takes one amplitude and one frequency")
        if args.input == "chirp":
            u = _signals.chirp(t, a[0], f0=f[0] / 10, f1=f[0], offset=args.offset)
        else:
            gen = _signals.sine if args.input == "sine" else _signals.triangle
            u = gen(t, a[0], f[0], offset=args.offset)
    desc = {"kind": args.input, "amplitude": a, "frequency": f, "offset": args.offset}
    desc.update(duration=args.duration, dt=args.dt)
    return t, np.asarray(u), desc


def _check_frequencies(freqs, dt) -> None:
    """A sine at 0 Hz, or at or above the Nyquist frequency 1 / (2 dt), is sampled as a constant
    (all zeros at 1 / dt) or an alias: refused rather than simulated."""
    nyquist = 0.5 / dt
    for f in freqs:
        if not f > 0:
            zero = " (0 Hz gives a constant input; --offset sets one)" if f == 0 else ""
            raise CLIError(f"--frequency {f:g} Hz: a frequency must be positive{zero}")
        if f >= nyquist:
            raise CLIError(
                f"--frequency {f:g} Hz is at or above the Nyquist frequency {nyquist:g} Hz "
                f"of --dt {dt:g}: the samples would show an alias, or nothing at all; "
                "lower --frequency or --dt"
            )


def _operator(args):
    if args.plays is not None:
        if args.thresholds is not None:
            raise CLIError("give either --thresholds or --plays, not both")
        if args.r_max is None:
            raise CLIError("--plays needs --r-max")
        r = np.arange(args.plays) * args.r_max / args.plays
    else:
        if args.r_max is not None:
            raise CLIError("--r-max is only used with --plays")
        r = np.asarray(args.thresholds if args.thresholds is not None else [0, 10 / 3, 20 / 3])
    if args.weights is None:
        w = np.array([1.0, 3.0, 5.0]) if len(r) == 3 else np.ones(len(r)) / len(r)
    else:
        w = np.asarray(args.weights)
    if len(w) != len(r):
        raise CLIError(f"{len(w)} weights for {len(r)} thresholds")
    x0 = np.asarray([0.0] if args.initial_states is None else args.initial_states)
    if len(x0) not in (1, len(r)):
        raise CLIError(f"{len(x0)} initial states for {len(r)} thresholds; give 1 or {len(r)}")
    return PIOperator(r, w, x0 if len(x0) > 1 else x0[0])


def _model(args):
    """The model of --model, refusing the operator options it would ignore."""
    from .._identification.model_file import load_model

    for name in ("thresholds", "plays", "r_max", "weights", "initial_states"):
        if getattr(args, name) is not None:
            raise CLIError(f"--{name.replace('_', '-')} describes a PI operator; --model runs {args.model} as it is")
    return load_model(args.model)


def _plays(model, u0) -> PIOperator:
    """The plays a model runs, as an operator (unit weights for a Preisach model's, started as the
    model starts them on an input beginning at `u0`)."""
    pi = getattr(model, "pi", None)
    return pi if pi is not None else PIOperator(model.half_widths, np.ones(model.shape[0]), model.init_state(u0))


def run(args) -> int:
    out = _io.check_outputs(args.out, OUTPUTS, args.force)
    model = None if args.model is None else _model(args)
    plain = _operator(args) if model is None else None
    t, u, desc = _input(args)
    if model is not None:
        check_creep_sampling(model, t, "the input")
    op = plain if plain is not None else _plays(model, u[0])
    if len(t) * op.n_plays > MAX_VALUES:
        raise CLIError(
            f"{len(t)} samples x {op.n_plays} plays is more than the {MAX_VALUES:.0e} values "
            "simulate.csv may hold; use fewer plays or samples"
        )
    memory.require(
        memory.bank_bytes(len(t), op.n_plays), f"{len(t)} samples x {op.n_plays} plays", "use fewer plays or samples"
    )
    H = np.asarray(op.regressor(u))
    y = np.asarray(op(u) if model is None else model(u))
    for name, v in (("input u", u), ("output y", y), ("play outputs", H)):
        # ptp catches both inf and a range too wide for float64 (which the plot cannot draw).
        with np.errstate(over="ignore", invalid="ignore"):
            wide = not np.isfinite(np.ptp(v))
        if wide:
            raise CLIError(
                f"the {name} overflows float64 (largest magnitude {np.max(np.abs(v)):.3g}); "
                "reduce --amplitude, --offset, --weights or --initial-states"
            )
    cols = {"t": t, "u": u, "y": y} | {f"x_{j + 1}": H[:, j] for j in range(H.shape[1])}
    written = [_io.write_csv(out / "simulate.csv", cols)]
    written.append(_io.save_figure(loop_figure(t, u, y, H, op.thresholds), out / "loop.png", dpi=120))
    if model is None:
        about = {"thresholds": op.thresholds, "weights": op.weights, "initial_states": op.initial_states}
    else:
        about = {"model": str(args.model), "structure": model.structure}
    summary = {
        **about,
        "input": desc,
        "n_samples": len(t),
        "y_min": float(y.min()),
        "y_max": float(y.max()),
        "final_states": H[-1],
    }
    written.append(_io.write_json(out / "simulate.json", summary))
    for p in written:
        print(p)
    return 0
