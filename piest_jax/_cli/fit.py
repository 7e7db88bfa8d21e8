"""`piest fit`: fit a PI model (thresholds, weights, offset) to a measured record."""

import argparse
import sys

import numpy as np

from .._data.record import load_record
from .._identification.compare import compare
from .._identification.covariance import table as parameter_table
from .._identification.fit import SOLVERS, fit_pi
from .._identification.model_file import model_keys
from .._identification.model_size import CRITERIA, HOLDOUT, holdout_mask, select_plays
from .._identification.model_structure import select_model
from . import fit_saturating, memory
from . import output as _io
from ._common import (
    CLIError,
    add_output_options,
    add_record_options,
    finite_float,
    float_list,
    positive_float,
    positive_int,
    seed,
)

NAME = "fit"
DESCRIPTION = """\
Fit y = sum_j w_j H_{r_j}[u] + sum_k c_k z_k[u] + offset to DATA.csv (header naming t, u, y)
by least squares through the play scan (Levenberg-Marquardt by default), thresholds included;
z_k is a first-order lag of u with time constant tau_k (creep), fitted jointly. Writes
  DIR/fit.json         model (structure, n_plays, n_lags), thresholds, weights, offset,
                       input_range (the record's smallest and largest input),
                       initial_states, creep (time_constants, weights, dt, starts_at_rest,
                       initial_states when fitted; absent for plain PI),
                       rmse (over the fitted samples), the solver's result, plays flagged as not
                       determined, std_errors (by parameter name; null when undetermined),
                       covariance (method, parameter_names, matrix), undetermined (names), the
                       selection's candidates, scores and rejected candidates, and with
                       --validate: validation_rmse (raw: the model run on VAL.csv from the
                       states named in validation_initial_states), validation_starts_at_rest,
                       validation_rmse_ic and validation_fit_percent (with VAL.csv's own output
                       offset and initial play and lag states estimated, nothing else)
  DIR/fit.md           the parameters as a value +- std error table (also on stderr)
  DIR/fit.png          the measured and fitted loops and the residual over time
  DIR/validation.png   the same for --validate VAL.csv (raw prediction)
Thresholds at or above half the input's peak-to-peak range cannot be excited and are flagged.
Standard errors are Newey-West (sandwich) estimates from the Jacobian at the solution, honest
for coloured residuals; a parameter whose standard error exceeds half its scale, or that the
Jacobian's rank leaves free, is undetermined: named on stderr and in fit.json, and never kept
by --plays auto or --model auto.
--model auto (the default) chooses plain PI or PI + creep by held-out error on the last 30 %
of the record: first the number of plays without creep, then 1, 2, ... lags (--lags) at that
play count, each kept only if it predicts the held-out block better; --model pi and
--model pi+creep fix the structure (with --lags K, or --time-constants T1,T2,... as the lags'
starting time constants in the record's time unit). --plays auto (the default) picks the number
of plays among --candidates, trying them from the smallest up and stopping after two in a row
that do not improve the score (--criterion bic only with --model pi; a progress bar shows on a
terminal unless --quiet). The validation record never takes part in choosing or fitting.
--fit-from T leaves the samples before time T (a start-up transient, a rest) out of the fit
and of its RMSE; they still drive the plays. Weights are kept positive (so the
model can be inverted by `piest compensate`) unless --signed-weights.

--model gpi fits y = offset + sum_k a_k tanh((v - c_k)/s_k), v = sum_j w_j H_{r_j}[u]: the PI's
loops bent into saturating ones (B-H loops, piezos at large drive), everything jointly, with
--terms K tanh terms (default 2) and --plays N (required); fit.json adds output_function
(amplitudes, centres, scales). --model preisach fits a discrete Preisach model on a --grid K,M
of half-widths and centres (default 16,16), its density smoothed (--smoothness, default chosen
on held-out blocks) and non-negative unless --signed-weights; fit.json holds the grid
(half_widths, centres, blur), the density, smoothness and the held-out scores. Both are
invertible by `piest compensate` (a signed Preisach density is not); neither is among
--model auto's choices, and options they would ignore are refused.

A candidate with a parameter the record does not determine (see fit.md) is never chosen: on the
Aye & Ang piezo pair (identify on one run, predict the other) the default keeps 8 plays and no
creep (validation_rmse 1.34, validation_rmse_ic 0.63), the creep candidates being undetermined.

example:  piest fit data.csv --validate val.csv --out fitted"""

OUTPUTS = ("fit.json", "fit.md", "fit.png", "validation.png")
# A standard error the record cannot bound is infinite: null in fit.json, listed in `undetermined`.
NONFINITE = ("std_errors",)


def plays_arg(text: str):
    if text == "auto":
        return "auto"
    try:
        return positive_int(text)
    except argparse.ArgumentTypeError as e:
        raise argparse.ArgumentTypeError(f"{e}; or 'auto'") from None


def _counts(what: str, one: str, example: str):
    """A parser of comma-separated distinct positive counts (plays, lags)."""

    def parse(text: str) -> list[int]:
        try:
            values = [positive_int(s.strip()) for s in text.split(",")]
        except argparse.ArgumentTypeError as e:
            raise argparse.ArgumentTypeError(f"expected {what} like {example}: {e}") from None
        if len(set(values)) != len(values):
            raise argparse.ArgumentTypeError(f"repeated {one} in {text!r}")
        return values

    return parse


plays_list = _counts("numbers of plays", "number of plays", "2,3,4")
lags_list = _counts("lag counts", "lag count", "1,2,3")
MODELS = ("auto", "pi", "pi+creep", *fit_saturating.MODELS)
CANDIDATES = (1, 2, 3, 4, 5, 6, 8, 10)
LAGS = (1, 2, 3)


def add_arguments(p):
    p.add_argument("data", metavar="DATA.csv", help="the identification record (t, u, y)")
    p.add_argument(
        "--model", choices=MODELS, default="auto",
        help="auto (default): choose pi or pi+creep by held-out error; pi: plays only; "
        "pi+creep: plays and a creep of first-order lags; gpi: plays, then a saturating "
        "output function (needs --plays N); preisach: a discrete Preisach model",
    )
    p.add_argument(
        "--lags", type=lags_list, default=None, metavar="K[,K...]",
        help="creep lag counts tried (default 1,2,3); one number fixes it",
    )
    p.add_argument(
        "--time-constants", type=float_list, default=None, metavar="T1[,T2...]",
        help="starting creep time constants (time units of t; fixes the lag count); each must "
        "lie between the sampling interval and 100 times the record's duration",
    )
    p.add_argument(
        "--plays",
        type=plays_arg,
        default="auto",
        metavar="N|auto",
        help="number of plays, or auto to choose it from the data (default auto)",
    )
    p.add_argument("--validate", metavar="VAL.csv", help="a second record to evaluate the fit on")
    p.add_argument("--solver", choices=SOLVERS, default="lm", help="lm (default), gn or bfgs")
    p.add_argument("--seed", type=seed, default=0, help="seed of the random starts (default 0)")
    p.add_argument("--starts", type=positive_int, default=4, help="starts solved at once (default 4)")
    p.add_argument(
        "--candidates",
        type=plays_list,
        default=None,
        help="numbers of plays tried by --plays auto (default 1,2,3,4,5,6,8,10)",
    )
    p.add_argument("--criterion", choices=CRITERIA, default=None,
                   help="how --plays auto chooses: holdout (default) or bic (with --model pi)")
    p.add_argument(
        "--initial-states",
        type=finite_float,
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
        type=finite_float,
        metavar="T",
        help="fit only the samples at time >= T (earlier ones still drive the plays)",
    )
    fit_saturating.add_arguments(p)
    add_record_options(p)
    add_output_options(p, "piest-fit")


def _rmse(a, b) -> float:
    return float(np.sqrt(np.mean((np.asarray(a) - np.asarray(b)) ** 2)))


def run(args) -> int:
    import jax

    # gpi and preisach: their own options checked first, their fit once the records are read.
    fit_saturating.refuse_ignored(args)
    if args.fit_initial_states and args.initial_states is not None:
        raise CLIError("give either --initial-states or --fit-initial-states, not both")
    _refuse_ignored(args)
    args.candidates = args.candidates or list(CANDIDATES)
    args.criterion = args.criterion or "holdout"
    args.lags = args.lags or list(LAGS)
    names = OUTPUTS if args.validate else OUTPUTS[:3]
    out = _io.check_outputs(args.out, names, args.force)
    rec = load_record(args.data, resample=args.resample, columns=args.columns)
    if np.ptp(rec.u) == 0:
        raise CLIError(f"{args.data}: the input u is constant ({rec.u[0]:g}): it excites no play, "
                       "so there is nothing to fit")
    val = load_record(args.validate, resample=args.resample, columns=args.columns) if args.validate else None
    mask = None
    if args.fit_from is not None:
        if not np.isfinite(args.fit_from):
            raise CLIError(f"--fit-from must be a finite time, got {args.fit_from}")
        mask = (rec.t >= args.fit_from).astype(float)
        if not mask.any():
            raise CLIError(f"{args.data}: no sample at or after --fit-from {args.fit_from:g} "
                           f"(the record ends at t = {rec.t[-1]:g})")
    n_used = rec.n_samples if mask is None else int(mask.sum())
    if args.model in fit_saturating.MODELS:
        return fit_saturating.run(args, rec, val, mask, out)
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
    if args.model == "pi" and args.time_constants is not None:
        raise CLIError("--time-constants needs --model pi+creep or auto, not --model pi")
    if args.criterion == "bic" and args.model != "pi":
        raise CLIError(f"--criterion bic chooses the plays only; use it with --model pi "
                       f"(--model {args.model} chooses by held-out error)")
    lags = list(args.lags)
    if args.time_constants is not None:
        _check_time_constants(args.time_constants, rec)
        lags = [len(args.time_constants)]
        opts["time_constants0"] = args.time_constants
    per_play = 3 if args.fit_initial_states else 2
    selection = None
    if args.model == "pi":
        lag_choices = [0]
    elif args.model == "pi+creep":
        lag_choices = lags
    else:
        lag_choices = [0] + lags
    plays = args.candidates if args.plays == "auto" else [args.plays]
    used = np.ones(rec.n_samples) if mask is None else mask
    if args.plays == "auto" or len(lag_choices) > 1:
        used = used * holdout_mask(rec.n_samples, HOLDOUT)
    n_fit = int(used.sum())
    if args.plays == "auto":
        cands = [c for c in plays if per_play * (c + max(lag_choices)) + 1 <= n_fit]
        if not cands:
            raise CLIError(
                f"{args.data}: {n_used} samples{'' if mask is None else ' from --fit-from on'} "
                "are too few to choose among --candidates "
                f"{','.join(map(str, args.candidates))} (each needs {per_play}n + 1 fitted "
                "samples, and a creep lag as many as a play)"
            )
    else:
        cands = plays
        # Lag counts the held-out part cannot carry are not tried; with none left the single
        # fit below names the shortage.
        fits = [k for k in lag_choices if per_play * (args.plays + k) + 1 <= n_fit]
        lag_choices = fits or lag_choices[:1]
    n_params = 3 * (max(cands) + max(lag_choices)) + 1
    memory.require(
        memory.fit_bytes(rec.n_samples, args.starts, n_params),
        f"--starts {args.starts} on {args.data} ({rec.n_samples} samples, up to {n_params} parameters)",
        "use fewer --starts, fewer plays or a shorter record",
    )
    if args.model == "pi" and args.plays == "auto":
        opts.pop("time_constants0", None)
        sel = select_plays(rec.u, rec.y, cands, criterion=args.criterion, quiet=args.quiet, **opts)
        f = sel.fit
        selection = {"criterion": sel.criterion, "candidates": sel.candidates, "scores": sel.scores,
                     "rejected": sel.rejected}
    elif len(cands) == 1 and len(lag_choices) == 1:
        f = fit_pi(rec.u, rec.y, cands[0], n_lags=lag_choices[0], dt=rec.dt, **opts)
    else:
        sel = select_model(rec.u, rec.y, rec.dt, cands, lag_choices, quiet=args.quiet, **opts)
        f = sel.fit
        base = [(c, s) for c, s in zip(sel.candidates, sel.scores) if c[1] == lag_choices[0]]
        selection = {
            "criterion": "holdout",
            "candidates": [c[0] for c, _ in base],
            "scores": [s for _, s in base],
            "models": [{"n_plays": c[0], "n_lags": c[1], "score": s,
                        "rejected": c in sel.rejected}
                       for c, s in zip(sel.candidates, sel.scores)],
        }
    model = f.model()
    # The model's keys (schema, structure, parameters, creep) as `save_model` writes them, so that
    # `load_model` reads fit.json back.
    report = {
        **model_keys(model),
        "data": str(args.data),
        "n_samples": rec.n_samples,
        "dt": rec.dt,
        "model": {"structure": model.structure, "n_plays": f.n_plays, "n_lags": f.n_lags},
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
        # Where the model has seen data: `piest compensate` reports inputs outside it.
        "input_range": [float(rec.u.min()), float(rec.u.max())],
        "n_fitted_samples": n_used,
        "std_errors": dict(zip(f.parameter_names, f.std_errors)),
        "covariance": {"method": f.covariance_method, "parameter_names": f.parameter_names,
                       "matrix": f.covariance},
        "undetermined": f.undetermined_names,
    }
    if f.creep is not None:
        report["creep"] = {
            "time_constants": f.creep.time_constants,
            "weights": f.creep.weights,
            "dt": f.creep.dt,
            # At rest: each lag starts at the first input of whatever record the model runs on.
            "starts_at_rest": f.creep.initial_states is None,
        }
        if f.creep.initial_states is not None:
            report["creep"]["initial_states"] = f.creep.initial_states
    if args.fit_from is not None:
        report["fit_from"] = args.fit_from
    if selection:
        report["selection"] = selection
    written = []
    if val is not None:
        if f.creep is not None and not np.isclose(val.dt, rec.dt, rtol=1e-3):
            raise CLIError(f"{args.validate}: sampled every {val.dt:g}, but the creep was "
                           f"identified at {rec.dt:g}; use records with the same sampling")
        m = model.with_initial_states(_validation_states(args, f, val))
        raw = compare(m, val.u, val.y, estimate_initial=False)
        ic = compare(m, val.u, val.y, estimate_initial=True)
        yv = np.asarray(raw.prediction)
        report["validate"] = str(args.validate)
        report["validation_initial_states"] = _state_convention(args)
        report["validation_starts_at_rest"] = starts_at_rest(val.u)
        report["validation_rmse"] = float(raw.rmse)
        report["validation_rmse_ic"] = float(ic.rmse)
        report["validation_fit_percent"] = float(ic.fit_percent)
        written.append(
            _io.save_figure(_figure(val, yv, "validation"), out / "validation.png", dpi=110)
        )
    written.insert(0, _io.save_figure(_figure(rec, np.asarray(f(rec.u)), "fit", mask),
                                      out / "fit.png", dpi=110))
    table = parameter_table(f)
    written.insert(0, _io.write_text(out / "fit.md", _markdown(args, f, table)))
    written.insert(0, _io.write_json(out / "fit.json", report))
    print(table, end="", file=sys.stderr)
    if f.undetermined_names:
        print(f"piest fit: warning: the record does not determine {', '.join(f.undetermined_names)} "
              "(standard error beyond half the parameter's scale, or free in the Jacobian's rank); "
              "predictions that depend on them are arbitrary: try fewer plays or lags",
              file=sys.stderr)
    elif np.any(np.asarray(f.flagged)):
        idx = [int(i) + 1 for i in np.flatnonzero(np.asarray(f.flagged))]
        print(f"piest fit: note: plays {idx} are not excited by the input; their thresholds are "
              "not determined by the data", file=sys.stderr)
    if val is not None and not report["validation_starts_at_rest"]:
        print(f"piest fit: note: {args.validate} does not start at rest, so the raw "
              "validation_rmse depends on the unknown states it starts from; "
              "validation_rmse_ic estimates them", file=sys.stderr)
    for p in written:
        print(p)
    return 0


def _refuse_ignored(args) -> None:
    """Options that the chosen mode would ignore are refused rather than dropped silently."""
    if args.plays != "auto":
        for given, name in ((args.candidates, "--candidates"), (args.criterion, "--criterion")):
            if given is not None:
                raise CLIError(f"{name} is used only by --plays auto; --plays {args.plays} fixes the "
                               "number of plays")
    if args.lags is not None:
        if args.model == "pi":
            raise CLIError("--lags needs --model pi+creep or auto, not --model pi (no creep)")
        if args.time_constants is not None:
            raise CLIError("give either --lags or --time-constants (whose count fixes the lags), not both")


def _check_time_constants(taus, rec) -> None:
    duration = rec.t[-1] - rec.t[0]
    for tau in taus:
        if not tau > 0:
            raise CLIError(f"--time-constants: {tau:g} is not positive; a creep time constant "
                           "must be a positive time")
        if tau < rec.dt:
            raise CLIError(f"--time-constants: {tau:g} is shorter than the sampling interval "
                           f"{rec.dt:g}: such a lag cannot be told from the input itself")
        if tau > 100 * duration:
            raise CLIError(f"--time-constants: {tau:g} is over 100 times the record's duration "
                           f"{duration:g}: such a lag cannot be told from an offset")


def starts_at_rest(u, fraction: float = 0.01, tolerance: float = 0.01) -> bool:
    """Whether a record starts at rest: its input moves by less than `tolerance` of its range
    over the first `fraction` of the record (at least two samples)."""
    u = np.asarray(u, float)
    head = u[: max(2, int(round(fraction * u.size)))]
    return bool(np.ptp(head) <= tolerance * max(np.ptp(u), np.finfo(float).tiny))


def _state_convention(args) -> str:
    if args.fit_initial_states:
        return "fitted (the identification record's)"
    if args.initial_states is not None:
        return f"given ({args.initial_states:g})"
    return "first input (every play and lag at rest at the validation record's first input)"


def _markdown(args, f, table) -> str:
    lines = [f"# piest fit: {args.data}", "",
             f"{f.model().structure}, {f.n_plays} plays, {f.n_lags} lags; RMSE {float(f.rmse):.4g}; "
             f"standard errors: {f.covariance_method}.", "", table]
    if f.undetermined_names:
        lines += [f"Undetermined by the record: {', '.join(f.undetermined_names)}.", ""]
    return "\n".join(lines)


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
