"""`piest compensate`: the feedforward input that cancels a fitted model's hysteresis."""

import sys

import numpy as np

from .._data.columns import base_name
from .._data.record import load_columns
from .._identification.compare import max_rate, outside_range
from .._identification.compensate import feedforward, started
from .._identification.figures import compensation_figure
from . import memory
from . import output as _io
from ._common import (
    CLIError,
    add_output_options,
    check_creep_sampling,
    columns_arg,
    finite_float,
    model_plays,
    positive_float,
)

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
  DIR/compensate.json   the model file, the plays' initial states used, the input's range and
                        fastest rate (max_rate), the largest |model - desired|, and the model's
                        fitted input range with the fraction of the input outside it (also
                        noted on stderr; absent when the model file does not say)
  DIR/compensate.png    desired output and feedforward input over time, and u against desired
A feedforward that leaves the model's fitted input range (fit.json's `input_range`) by more
than 5% of its width, or that changes faster than --max-slew, is refused (exit 2, nothing
written) unless --clip (held inside the range and the slew rate; compensate.json's n_clipped
counts the samples changed) or --extrapolate; one faster than anything in the record the model
was fitted on (fit.json's input_max_rate) is noted.
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
    p.add_argument(
        "--max-slew",
        type=positive_float,
        default=None,
        metavar="RATE",
        help="the fastest |du/dt| allowed (input units per time unit); a faster feedforward is refused",
    )
    p.add_argument(
        "--clip",
        action="store_true",
        help="clip the feedforward into the fitted input range (and to --max-slew) instead of refusing it",
    )
    add_output_options(p, "piest-compensate")


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
    from .._identification.model_file import model_from_keys, read_json

    out = _io.check_outputs(args.out, OUTPUTS, args.force)
    if args.clip and args.extrapolate:
        raise CLIError("give either --clip or --extrapolate, not both")
    keys = read_json(args.model)
    model = model_from_keys(keys, str(args.model))
    limits = _limits(keys)
    if args.columns is not None and args.column is not None:
        raise CLIError("give either --column or --columns, not both")
    t, yd, col = load_desired(args.desired, args.column, args.columns)
    check_creep_sampling(model, t, str(args.desired))
    n = model_plays(model)
    memory.require(
        memory.stream_bytes(len(t), n),
        f"{args.model} ({n} plays) on {args.desired} ({len(t)} samples)",
        "use a shorter desired output or a model with fewer plays",
    )
    x0 = None if args.initial_states is None else np.full(n, args.initial_states)
    try:
        model = started(model, x0)  # the states its output below starts from, as the inverse's
        u = np.asarray(feedforward(model, yd))
    except ValueError as e:
        # The desired output was checked on reading: what is left is the model (not invertible).
        raise CLIError(f"{args.model}: {' '.join(str(e).split())}") from None
    summary: dict = {}
    if args.clip:
        if limits["range"] is None and args.max_slew is None:
            raise CLIError(f"{args.model}: states no fitted input range to clip to (give --max-slew, or a fit.json)")
        limited = _limited(t, u, limits["range"], args.max_slew)
        summary["n_clipped"] = int(np.sum(limited != u))
        u = limited
    rate = max_rate(t, u)
    if not args.clip and args.max_slew is not None and rate > args.max_slew:
        raise CLIError(
            f"{args.model}: the feedforward changes at up to {rate:.6g} per time unit, faster than "
            f"--max-slew {args.max_slew:.6g}; ask for a slower desired output, or pass --clip"
        )
    if limits["rate"] is not None and rate > 1.05 * limits["rate"]:
        print(
            f"piest compensate: note: the feedforward changes at up to {rate:.6g} per time unit, "
            f"faster than anything in the record the model was fitted on ({limits['rate']:.6g}); "
            "--max-slew bounds it",
            file=sys.stderr,
        )
    summary |= _outside(args.model, u, limits["range"], args.extrapolate)
    # The model's own run from the states the feedforward started from (a creep's lags at rest at
    # the first input unless the file states theirs).
    ym = np.asarray(model(u))
    problem = model.inverse_problem()
    if problem is not None:
        print(f"piest compensate: note: {args.model}: {problem}", file=sys.stderr)
    # None: a Preisach model's plays at rest at the first input.
    states = getattr(getattr(model, "pi", model), "initial_states")
    head = {"structure": model.structure} if model.structure in ("gpi", "preisach") else {}
    written = [_io.write_csv(out / "compensate.csv", {"t": t, "desired": yd, "u": u, "model": ym})]
    summary = {
        "model": str(args.model),
        **head,
        "desired": str(args.desired),
        "column": col,
        "n_samples": len(t),
        "initial_states": None if states is None else np.asarray(states),
        "u_min": float(u.min()),
        "u_max": float(u.max()),
        "max_model_error": float(np.max(np.abs(ym - yd))),
        "max_rate": rate,
        **summary,
    }
    written.append(_io.write_json(out / "compensate.json", summary))
    figure = compensation_figure(t, yd, u, input_range=limits["range"])
    written.append(_io.save_figure(figure, out / "compensate.png", dpi=110))
    for p in written:
        print(p)
    return 0


def _limits(keys) -> dict:
    """The fitted input `range` (fit.json's `input_range`) and the fastest input `rate` of the
    record it was fitted on (`input_max_rate`) in a model file's keys; None where it does not say."""

    def number(v):
        return isinstance(v, int | float) and not isinstance(v, bool) and np.isfinite(v)

    rng = keys.get("input_range")
    ok = isinstance(rng, list) and len(rng) == 2 and all(number(v) for v in rng) and rng[0] <= rng[1]
    rate = keys.get("input_max_rate")
    return {
        "range": (float(rng[0]), float(rng[1])) if ok else None,
        "rate": float(rate) if number(rate) and rate > 0 else None,
    }


def _limited(t, u, rng, max_slew) -> np.ndarray:
    """`u` held inside `rng` (lo, hi) and, sample by sample, to at most `max_slew` per time unit
    from the sample before (either None: no such limit)."""
    lo, hi = (-np.inf, np.inf) if rng is None else rng
    if max_slew is None:
        return np.clip(u, lo, hi)
    out = np.empty_like(u)
    prev = None
    for i, v in enumerate(u):
        if prev is not None:
            step = max_slew * (t[i] - t[i - 1])
            v = min(max(v, prev - step), prev + step)
        out[i] = prev = min(max(v, lo), hi)
    return out


# A feedforward may leave the fitted input range by this share of the range's width before it is
# refused: rounding and measurement noise in a desired output taken from a record stay inside it.
RANGE_MARGIN = 0.05


def _outside(path, u, rng, extrapolate: bool) -> dict:
    """The fitted input range `rng` and the fraction of the feedforward input outside it; a note
    on stderr when there is any, a `CLIError` when the input leaves the range by more than
    `RANGE_MARGIN` of its width and `extrapolate` is False."""
    if rng is None:
        return {}  # the model file does not say (not written by `piest fit`, or an older one)
    lo, hi = rng
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
            "output the model reached when fitted, or pass --clip or --extrapolate"
        )
    if n_out:
        print(
            f"piest compensate: note: {share} of the feedforward input lie outside the input range "
            f"the model was fitted on {where}; the model is extrapolated there",
            file=sys.stderr,
        )
    return {"fitted_input_range": [lo, hi], "fraction_outside_fitted_range": frac}
