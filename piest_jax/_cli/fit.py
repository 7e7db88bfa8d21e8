"""`piest fit`: fit a PI model (thresholds, weights, offset) to a measured record."""

import argparse
import sys

import numpy as np

from . import output as _io
from .._data.record import load_record
from .._identification.fit import SOLVERS, fit_pi
from .._identification.model_file import model_keys
from .._identification.model_size import CRITERIA, HOLDOUT, holdout_mask, select_plays
from ._common import CLIError, add_output_options, positive_float, positive_int

NAME = "fit"
DESCRIPTION = """\
Fit y = sum_j w_j H_{r_j}[u] + offset to DATA.csv (header naming t, u, y) by least squares
through the play scan (Levenberg-Marquardt by default), thresholds included, and write
  DIR/fit.json         thresholds, weights, offset, initial_states, rmse (over the fitted
                       samples), validation_rmse (with --validate), the solver's result, plays
                       flagged as not excited, and with --plays auto the candidates and scores
  DIR/fit.png          the measured and fitted loops and the residual over time
  DIR/validation.png   the same for --validate VAL.csv
Thresholds at or above half the input's peak-to-peak range cannot be excited and are flagged.
--plays auto (the default) picks the number of plays among --candidates by held-out error
on the last 30 % of the record (or --criterion bic), trying them from the smallest up and
stopping after two in a row that do not improve the score (a progress bar shows on a terminal
unless --quiet). --fit-from T leaves the samples before time T (a start-up transient, a rest)
out of the fit and of its RMSE; they still drive the plays. Weights are kept positive (so the
model can be inverted by `piest compensate`) unless --signed-weights.

example:  piest fit data.csv --plays 4 --validate val.csv --out fitted"""

OUTPUTS = ("fit.json", "fit.png", "validation.png")


def plays_arg(text: str):
    if text == "auto":
        return "auto"
    try:
        return positive_int(text)
    except argparse.ArgumentTypeError as e:
        raise argparse.ArgumentTypeError(f"{e}; or 'auto'") from None


def plays_list(text: str) -> list[int]:
    items = [s.strip() for s in text.split(",")]
    try:
        values = [positive_int(s) for s in items]
    except argparse.ArgumentTypeError as e:
        raise argparse.ArgumentTypeError(f"expected positive whole numbers like 2,3,4: {e}") from None
    if len(set(values)) != len(values):
        raise argparse.ArgumentTypeError(f"repeated number of plays in {text!r}")
    return values


def add_arguments(p):
    p.add_argument("data", metavar="DATA.csv", help="the identification record (t, u, y)")
    p.add_argument(
        "--plays",
        type=plays_arg,
        default="auto",
        metavar="N|auto",
        help="number of plays, or auto to choose it from the data (default auto)",
    )
    p.add_argument("--validate", metavar="VAL.csv", help="a second record to evaluate the fit on")
    p.add_argument("--solver", choices=SOLVERS, default="lm", help="lm (default), gn or bfgs")
    p.add_argument("--seed", type=int, default=0, help="seed of the random starts (default 0)")
    p.add_argument("--starts", type=positive_int, default=4, help="starts solved at once (default 4)")
    p.add_argument(
        "--candidates",
        type=plays_list,
        default=[1, 2, 3, 4, 5, 6, 8, 10],
        help="numbers of plays tried by --plays auto (default 1,2,3,4,5,6,8,10)",
    )
    p.add_argument("--criterion", choices=CRITERIA, default="holdout", help="for --plays auto")
    p.add_argument(
        "--initial-states",
        type=float,
        default=None,
        metavar="X",
        help="the plays' state before each record (default: each record's first input)",
    )
    p.add_argument(
        "--fit-initial-states", action="store_true", help="fit the initial states as well"
    )
    p.add_argument("--signed-weights", action="store_true", help="allow negative weights")
    p.add_argument(
        "--max-threshold", type=positive_float, help="upper bound on every threshold (u units)"
    )
    p.add_argument("--max-steps", type=positive_int, default=100, help="solver steps (default 100)")
    p.add_argument(
        "--fit-from",
        type=float,
        metavar="T",
        help="fit only the samples at time >= T (earlier ones still drive the plays)",
    )
    p.add_argument(
        "--resample", action="store_true", help="interpolate non-uniform time onto a uniform grid"
    )
    add_output_options(p, "piest-fit")


def _rmse(a, b) -> float:
    return float(np.sqrt(np.mean((np.asarray(a) - np.asarray(b)) ** 2)))


def run(args) -> int:
    import jax

    if args.fit_initial_states and args.initial_states is not None:
        raise CLIError("give either --initial-states or --fit-initial-states, not both")
    names = OUTPUTS if args.validate else OUTPUTS[:2]
    out = _io.check_outputs(args.out, names, args.force)
    rec = load_record(args.data, resample=args.resample)
    if np.ptp(rec.u) == 0:
        raise CLIError(f"{args.data}: the input u is constant ({rec.u[0]:g}): it excites no play, "
                       "so there is nothing to fit")
    val = load_record(args.validate, resample=args.resample) if args.validate else None
    mask = None
    if args.fit_from is not None:
        if not np.isfinite(args.fit_from):
            raise CLIError(f"--fit-from must be a finite time, got {args.fit_from}")
        mask = (rec.t >= args.fit_from).astype(float)
        if not mask.any():
            raise CLIError(f"{args.data}: no sample at or after --fit-from {args.fit_from:g} "
                           f"(the record ends at t = {rec.t[-1]:g})")
    n_used = rec.n_samples if mask is None else int(mask.sum())
    opts = dict(
        mask=mask,
        solver=args.solver,
        n_starts=args.starts,
        key=jax.random.key(args.seed),
        positive_weights=not args.signed_weights,
        fit_initial_states=args.fit_initial_states,
        initial_states=args.initial_states,
        max_threshold=args.max_threshold,
        max_steps=args.max_steps,
    )
    selection = None
    if args.plays == "auto":
        # A candidate needs 2n + 1 parameters (3n + 1 with fitted states) on the fitted samples.
        per_play = 3 if args.fit_initial_states else 2
        used = np.ones(rec.n_samples) if mask is None else mask
        if args.criterion == "holdout":
            used = used * holdout_mask(rec.n_samples, HOLDOUT)
        n_fit = int(used.sum())
        cands = [c for c in args.candidates if per_play * c + 1 <= n_fit]
        if not cands:
            raise CLIError(
                f"{args.data}: {n_used} samples{'' if mask is None else ' from --fit-from on'} "
                "are too few to choose among --candidates "
                f"{','.join(map(str, args.candidates))} (each needs {per_play}n + 1 fitted samples)"
            )
        sel = select_plays(rec.u, rec.y, cands, criterion=args.criterion, quiet=args.quiet, **opts)
        f = sel.fit
        selection = {"criterion": sel.criterion, "candidates": sel.candidates, "scores": sel.scores}
    else:
        f = fit_pi(rec.u, rec.y, args.plays, **opts)
    # The model's keys (schema, structure, parameters) as `save_model` writes them, so that
    # `load_model` reads fit.json back.
    report = {
        **model_keys(f),
        "data": str(args.data),
        "n_samples": rec.n_samples,
        "n_plays": f.n_plays,
        "rmse": f.rmse,
        "flagged": f.flagged,
        "solver": {
            "name": args.solver,
            "result": f.result_name,
            "steps": f.n_steps,
            "start_rmse": f.start_rmse,
        },
        "input_half_range": 0.5 * float(np.ptp(rec.u)),
        "n_fitted_samples": n_used,
    }
    if args.fit_from is not None:
        report["fit_from"] = args.fit_from
    if selection:
        report["selection"] = selection
    written = []
    if val is not None:
        x0 = _validation_states(args, f, val)
        yv = np.asarray(f(val.u, x0))
        report["validate"] = str(args.validate)
        report["validation_rmse"] = _rmse(yv, val.y)
        written.append(
            _io.save_figure(_figure(val, yv, "validation"), out / "validation.png", dpi=110)
        )
    written.insert(0, _io.save_figure(_figure(rec, np.asarray(f(rec.u)), "fit", mask),
                                      out / "fit.png", dpi=110))
    written.insert(0, _io.write_json(out / "fit.json", report))
    if np.any(np.asarray(f.flagged)):
        idx = [int(i) + 1 for i in np.flatnonzero(np.asarray(f.flagged))]
        print(f"piest fit: note: plays {idx} are not excited by the input; their thresholds are "
              "not determined by the data", file=sys.stderr)
    for p in written:
        print(p)
    return 0


def _validation_states(args, f, val):
    if args.fit_initial_states:
        return f.initial_states
    return val.u[0] if args.initial_states is None else args.initial_states


def _figure(rec, ym, what, mask=None):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    used = slice(None) if mask is None else mask > 0
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4))
    a1.plot(rec.u[used], rec.y[used], "k", lw=0.7, label="measured")
    a1.plot(rec.u[used], ym[used], "C1", lw=0.7, label="model")
    a1.set(xlabel="input u", ylabel="output y", title=f"{what}: loop")
    a1.legend(fontsize=8)
    a2.plot(rec.t, rec.y - ym, lw=0.6)
    if mask is not None and not mask.all():
        a2.axvspan(rec.t[0], rec.t[np.argmax(mask > 0)], color="0.85", label="not fitted")
        a2.legend(fontsize=8)
        # Scaled to the fitted samples: a transient left out would otherwise flatten the rest.
        e = (rec.y - ym)[used]
        pad = 0.1 * max(np.ptp(e), 1e-12)
        a2.set_ylim(e.min() - pad, e.max() + pad)
    rmse = _rmse(ym[used], rec.y[used])
    a2.set(xlabel="time", ylabel="y - model", title=f"residual, RMSE {rmse:.4g}")
    fig.tight_layout()
    return fig
