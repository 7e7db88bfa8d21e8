"""`piest compensate`: the feedforward input that cancels a fitted model's hysteresis."""

import sys

import numpy as np

from .._data.columns import base_name
from .._data.record import load_columns
from .._identification.compare import outside_range
from .._identification.compensate import admissible_states, feedforward
from .._identification.figures import compensation_figure
from .._models.composite import HysteresisModel
from .._models.gpi import GeneralizedPI
from .._models.preisach import Preisach
from .._operators.pi import PIOperator
from . import memory
from . import output as _io
from ._common import CLIError, add_output_options, columns_arg, finite_float

NAME = "compensate"
DESCRIPTION = """\
Invert the model in MODEL.json (as written by `piest fit`: thresholds, weights, offset,
initial_states, and creep when the fit has one) and compute u = P^-1[desired - offset] for the
desired output in DESIRED.csv; with creep, sample by sample u = Q^-1[desired - offset - the
lags' memory of the past input], Q the PI with the lags' share of the present input folded into
its first weight (the exact inverse of PI + creep; DESIRED.csv must then be sampled at the
model's dt) (a header naming `t` and the column given by --column, default `desired`, else `y`).
Writes
  DIR/compensate.csv    columns t, desired, u (the feedforward input) and model (the model's
                        output for u, equal to desired up to rounding)
  DIR/compensate.json   the model file, the plays' initial states used, the input's range,
                        the largest |model - desired|, and the model's fitted input range with
                        the fraction of the input outside it (also noted on stderr; absent when
                        the model file does not say)
  DIR/compensate.png    desired output and feedforward input over time, and u against desired
A feedforward that leaves the model's fitted input range (fit.json's `input_range`) by more
than 5% of its width is refused (exit 2, nothing written) unless --extrapolate.
The model must be invertible: r_1 = 0 and positive cumulative weights (fit without
--signed-weights to guarantee it).
A generalized PI (`piest fit --model gpi`) is inverted as u = P^-1[g^-1(desired)], g its
saturating output function: a desired output beyond the range it saturates at is refused. A
Preisach model (`--model preisach`) is inverted sample by sample by bisection; its density must
be non-negative (fit without --signed-weights), and a desired output beyond its reach gives the
nearest end of its input range (max_model_error in compensate.json shows it). --initial-states
sets their plays' states; by default a Preisach model starts at rest at the first input.

example:  piest compensate fitted/fit.json desired.csv --out ff"""

OUTPUTS = ("compensate.csv", "compensate.json", "compensate.png")


def add_arguments(p):
    p.add_argument("model", metavar="MODEL.json", help="a model written by `piest fit`")
    p.add_argument("desired", metavar="DESIRED.csv", help="CSV with t and the desired output")
    p.add_argument("--column", default=None, help="the desired-output column (default desired, y)")
    p.add_argument(
        "--columns",
        type=columns_arg(2, "time_s,target_um"),
        metavar="TIME,DESIRED",
        help="DESIRED.csv's names of its time and desired-output columns (instead of t and --column)",
    )
    p.add_argument(
        "--initial-states",
        type=finite_float,
        default=None,
        metavar="X",
        help="the plays' state at the start (default: the model's, made admissible)",
    )
    p.add_argument(
        "--extrapolate",
        action="store_true",
        help="write a feedforward that leaves the model's fitted input range (refused otherwise)",
    )
    add_output_options(p, "piest-compensate")


def load_model(path):
    """Thresholds, weights, offset, initial states and creep (or None) of a model file (`piest
    fit`'s fit.json), read by the library's `load_model`, so errors name the file and the problem."""
    from .._identification.model_file import load_model as read_model
    from .._identification.pi_model import PIModel

    model = read_model(path)
    if isinstance(model, HysteresisModel):
        op, creep, c = model.pi, model.creep, model.offset
    elif isinstance(model, PIModel):
        op, creep, c = model.operator(), None, model.offset
    else:
        raise CLIError(f"{path}: a {type(model).__name__} has no inverse here")
    return (*(np.asarray(a) for a in (op.thresholds, op.weights, c, op.initial_states)), creep)


def load_desired(path, column, columns=None):
    """Time and desired output from a CSV with a header row (read by `load_columns`, so errors
    name the file, row and problem); `columns`, the file's names for the two (default `t` and
    `column`)."""
    if columns is not None:
        time, col = (base_name(c) for c in columns)
        cols = load_columns(path, (time, col), time=time)
        return cols[time], cols[col], col
    names = load_columns(path, ("t",))
    col = (column or ("desired" if "desired" in names else "y")).lower()
    if col not in names:
        raise CLIError(f"{path}: no column `{col}` in the header ({', '.join(names)})")
    cols = load_columns(path, ("t", col))
    return cols["t"], cols[col], col


def run(args) -> int:
    out = _io.check_outputs(args.out, OUTPUTS, args.force)
    own = _own_inverse_model(args.model)
    if own is None:
        r, w, c, x0, creep = load_model(args.model)
    if args.columns is not None and args.column is not None:
        raise CLIError("give either --column or --columns, not both")
    t, yd, col = load_desired(args.desired, args.column, args.columns)
    if own is not None:
        return _run_own_inverse(args, out, own, t, yd, col)
    if creep is not None and len(t) > 1:
        dt = float(np.median(np.diff(t)))
        if not np.isclose(dt, creep.dt, rtol=1e-3):
            raise CLIError(
                f"{args.desired}: sampled every {dt:g}, but the model's creep was "
                f"identified at dt = {creep.dt:g}; resample the desired output"
            )
    memory.require(
        memory.stream_bytes(len(t), len(r)),
        f"{args.model} ({len(r)} plays) on {args.desired} ({len(t)} samples)",
        "use a shorter desired output or a model with fewer plays",
    )
    if args.initial_states is not None:
        x0 = np.full(r.shape, args.initial_states)
    try:
        x0 = np.asarray(admissible_states(r, x0))
        op = PIOperator(r, w, x0)
        model = op if creep is None else HysteresisModel(op, creep, c)
        u = np.asarray(feedforward(model, yd, offset=c))
    except ValueError as e:
        # The desired output was checked on reading: what is left is the model (not invertible).
        raise CLIError(f"{args.model}: {' '.join(str(e).split())}") from None
    ym = np.asarray(op(u)) + c
    if creep is not None:
        # The model's own run: its lags at rest at the first input, as the feedforward assumed
        # unless the file states their states.
        ym = np.asarray(model(u))
        steady = float(np.sum(np.asarray(creep.weights)))
        if float(w[0]) + steady <= 0:
            print(
                f"piest compensate: note: {args.model}: the creep's steady gain ({steady:.4g}) outweighs "
                f"the first play's weight ({float(w[0]):.4g}), so the model's static map falls where only "
                "that play moves; the feedforward can drift on a slowly varying desired output",
                file=sys.stderr,
            )
    return _write(args, out, t, yd, u, ym, {"column": col, "initial_states": x0})


def _own_inverse_model(path) -> GeneralizedPI | Preisach | None:
    """The generalized PI or Preisach model in a model file, or None for a PI model."""
    from .._identification.model_file import load_model as read_model

    model = read_model(path)
    return model if isinstance(model, GeneralizedPI | Preisach) else None


def _run_own_inverse(args, out, model, t, yd, col) -> int:
    """`piest compensate` for a model that carries its own inverse (gpi, preisach)."""
    gpi = isinstance(model, GeneralizedPI)
    n_plays = model.n_plays if gpi else model.shape[0]
    memory.require(
        memory.stream_bytes(len(t), n_plays),
        f"{args.model} ({n_plays} plays) on {args.desired} ({len(t)} samples)",
        "use a shorter desired output or a model with fewer plays",
    )
    if args.initial_states is not None:
        x0 = np.full(n_plays, args.initial_states)
        model = model.with_initial_states(admissible_states(model.pi.thresholds, x0) if gpi else x0)
    try:
        u = np.asarray(feedforward(model, yd))
    except ValueError as e:
        raise CLIError(f"{args.model}: {' '.join(str(e).split())}") from None
    ym = np.asarray(model(u))
    states = model.pi.initial_states if gpi else model.initial_states
    # None: a Preisach model's plays at rest at the first input.
    return _write(
        args,
        out,
        t,
        yd,
        u,
        ym,
        {
            "structure": "gpi" if gpi else "preisach",
            "column": col,
            "initial_states": None if states is None else np.asarray(states),
        },
    )


def _write(args, out, t, yd, u, ym, fields) -> int:
    """compensate.csv, compensate.json (the model's `fields` among the summary) and the figure."""
    outside = _outside(args.model, u, args.extrapolate)
    written = [_io.write_csv(out / "compensate.csv", {"t": t, "desired": yd, "u": u, "model": ym})]
    summary = {
        "model": str(args.model),
        **{k: fields[k] for k in ("structure",) if k in fields},
        "desired": str(args.desired),
        "column": fields["column"],
        "n_samples": len(t),
        "initial_states": fields["initial_states"],
        "u_min": float(u.min()),
        "u_max": float(u.max()),
        "max_model_error": float(np.max(np.abs(ym - yd))),
    } | outside
    written.append(_io.write_json(out / "compensate.json", summary))
    written.append(_io.save_figure(compensation_figure(t, yd, u), out / "compensate.png", dpi=110))
    for p in written:
        print(p)
    return 0


# A feedforward may leave the fitted input range by this share of the range's width before it is
# refused: rounding and measurement noise in a desired output taken from a record stay inside it.
RANGE_MARGIN = 0.05


def _outside(path, u, extrapolate: bool) -> dict:
    """The fitted input range (fit.json's `input_range`) and the fraction of the feedforward
    input outside it; a note on stderr when there is any, a `CLIError` when the input leaves the
    range by more than `RANGE_MARGIN` of its width and `extrapolate` is False."""
    from .._identification.model_file import read_json

    rng = read_json(path).get("input_range")
    ok = (
        isinstance(rng, list)
        and len(rng) == 2
        and all(isinstance(v, int | float) and not isinstance(v, bool) for v in rng)
    )
    if not ok or not all(np.isfinite(rng)) or rng[0] > rng[1]:
        return {}  # the model file does not say (not written by `piest fit`, or an older one)
    lo, hi = float(rng[0]), float(rng[1])
    n_out = int(np.sum(outside_range(u, (lo, hi))))
    frac = n_out / u.size
    pct = f"{frac:.1%}" if frac >= 0.001 else "<0.1%"
    share = f"{n_out} of {u.size} samples ({pct})" if n_out else ""
    where = f"[{lo:.6g}, {hi:.6g}] (u from {u.min():.6g} to {u.max():.6g})"
    margin = RANGE_MARGIN * (hi - lo)
    if not extrapolate and (u.min() < lo - margin or u.max() > hi + margin):
        raise CLIError(
            f"{path}: the feedforward leaves the input range the model was fitted on by more than "
            f"{RANGE_MARGIN:.0%} of its width: {share} lie outside {where}; ask for a desired "
            "output the model reached when fitted, or pass --extrapolate"
        )
    if n_out:
        print(
            f"piest compensate: note: {share} of the feedforward input lie outside the input range "
            f"the model was fitted on {where}; the model is extrapolated there",
            file=sys.stderr,
        )
    return {"fitted_input_range": [lo, hi], "fraction_outside_fitted_range": frac}
