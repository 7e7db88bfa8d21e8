"""`piest fit`: fit a PI model (thresholds, weights, offset) to a measured record."""

import argparse
import sys

import numpy as np

from .._identification.band import prediction_band
from .._identification.covariance import table as parameter_table
from .._identification.figures import fit_figure
from .._identification.fit import LONG_RECORD, SOLVERS, PIFit
from .._identification.fit_gpi import GPIFit
from .._identification.fit_preisach import PreisachFit
from .._identification.identify import MODELS, SATURATING, check_options, fit_mask, identify, plan
from .._identification.model_size import CRITERIA
from . import fit_saturating, memory
from . import output as _io
from ._common import (
    CLIError,
    add_output_options,
    add_record_options,
    add_spike_option,
    finite_float,
    float_list,
    note_extrapolation,
    note_loop,
    positive_float,
    positive_int,
    read_record,
    record_fields,
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
                       covariance (method, parameter_names, matrix), undetermined (names),
                       invertible (and inverse_problem when not, also noted on stderr), the
                       selection's candidates, scores and rejected candidates, and with
                       --validate: validation_rmse (raw: the model run on VAL.csv from the
                       states named in validation_initial_states), validation_starts_at_rest,
                       validation_rmse_ic and validation_fit_percent (with VAL.csv's own output
                       offset and initial play and lag states estimated, nothing else),
                       validation_band_coverage and validation_band_coverage_ic (the fraction
                       of VAL.csv's samples inside the raw and the IC prediction's 95 %
                       measurement band: the parameters' covariance through the model's
                       Jacobian on VAL.csv, plus the residuals' variance; 0.95 if calibrated),
                       validation_outside_input_range (the fraction of VAL.csv's samples whose
                       input lies outside input_range, where the model extrapolates: a note
                       says so) and validation_inside_input_range (rmse, and rmse_ic where
                       there is an IC estimate, over the others)
  DIR/fit.md           the parameters as a value +- std error table (also on stderr, unless --quiet)
  DIR/fit.png          the measured and fitted loops and the residual over time, with the
                       95 % measurement band shaded
  DIR/validation.png   the same for --validate VAL.csv (raw prediction)
Thresholds at or above half the input's peak-to-peak range cannot be excited and are flagged.
Standard errors are Newey-West (sandwich) estimates from the Jacobian at the solution, honest
for coloured residuals; a parameter whose standard error exceeds half its scale, or that the
Jacobian's rank leaves free, is undetermined: named on stderr and in fit.json, and never kept
by --plays auto or --model auto.
--model auto (the default) chooses plain PI or PI + creep by held-out error on the last 30 %
of the record (of its first 262,144 samples on a longer record, the chosen model then fitted on
all; fit.json's selection_samples): first the number of plays without creep, then 1, 2, ...
lags (--lags) at that play count, each kept only if it predicts the held-out block better;
--model pi and --model pi+creep fix the structure (with --lags K, or --time-constants T1,T2,... as the lags'
starting time constants in the record's time unit). --plays auto (the default) picks the number
of plays among --candidates, trying them from the smallest up and stopping after two in a row
that do not improve the score (--criterion bic only with --model pi; a progress bar shows on a
terminal unless --quiet). The validation record never takes part in choosing or fitting.
--fit-from T leaves the samples before time T (a start-up transient, a rest) out of the fit
and of its RMSE; they still drive the plays. Weights, the creep lags' included, are kept
positive (so the model can be inverted by `piest compensate`) unless --signed-weights, or unless the record's
loop runs clockwise (the output leads the input, as an inverse PI does: positive weights would
fit it with a straight line), which fit.json's loop (direction, score) and a note say.

--model gpi fits y = offset + sum_k a_k tanh((v - c_k)/s_k), v = sum_j w_j H_{r_j}[u]: the PI's
loops bent into saturating ones (B-H loops, piezos at large drive), everything jointly, with
--terms K tanh terms (default 2) and --plays N (required); fit.json adds output_function
(amplitudes, centres, scales) and, as for PI, std_errors, covariance and undetermined for its
parameters (output.amplitudes[k], output.centres[k], output.scales[k]: s_1 = 1 is fixed), with
the value +- std error table in fit.md and on stderr. --model preisach fits a discrete Preisach model on a --grid K,M
of half-widths and centres (default 16,16), its density smoothed (--smoothness, default chosen
on held-out blocks) and non-negative unless --signed-weights; fit.json holds the grid
(half_widths, centres, blur), the density, smoothness, the held-out scores, and std_errors,
covariance and undetermined for its cells (density[k,m]) and offset: the penalised estimate's
spread over the noise at the chosen smoothness (a cell held at 0 by the non-negativity has
std error 0). For both, fit.png and validation.png shade the 95 % measurement band and
fit.json has validation_band_coverage (of the raw prediction, the only one they have). Both are
invertible by `piest compensate` (a signed Preisach density is not); options they would ignore
are refused. --model auto also tries a non-negative 16 x 16 Preisach model (with --plays auto,
non-negative weights and unfitted initial states): scored on the same held-out block, fitted on
the whole record only if it scores better than the best PI candidate by 1 %, and chosen only if
that fit leaves no parameter undetermined (fit.json's selection.preisach: score, undetermined,
chosen): a record that repeats one loop never determines it (Aye: 93 of 145). Where the output
saturates (a saturating function of a 16-play positive-weight PI's output leaves at most half its
error), --model auto also tries the generalized PI with 2, 3, 4, 6, 8 plays on the same block,
chosen only if it beats the best model so far by 1 % with every parameter determined
(selection.gpi: gate, plays, scores, n_plays, score, undetermined, chosen).

A candidate with a parameter the record does not determine (see fit.md; judged on the whole
record, held-out block included) is never chosen; one with creep that would have scored best is
tried with fewer plays instead. On the Chandra piezo record identified on its first 7 s and run
on 7-9 s the default keeps 2 plays and a 23 s lag (validation_rmse_ic 0.111 um). On the
Aye & Ang piezo pair (identify on one run, predict the other) the default keeps 8 plays and 3
lags (tau 0.05 s and 0.16 s held on their bounds, 9.4 s; validation_rmse 0.54,
validation_rmse_ic 0.31; plain PI: 1.34 and 0.63).
Creep time constants are kept ordered, at least sqrt(10) apart and no faster than the input's
reversals allow (pj.shortest_time_constant); creep weights are free in sign (a lag the fit
leaves on one of those bounds is held there: fit.json's held_on_bounds, "on its bound" in fit.md).

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


def add_arguments(p):
    p.add_argument("data", metavar="DATA.csv", help="the identification record (t, u, y)")
    p.add_argument(
        "--model",
        choices=MODELS,
        default="auto",
        help="auto (default): choose pi, pi+creep or (where the record determines them) preisach, or gpi "
        "where the output saturates, by held-out error; pi: plays only; "
        "pi+creep: plays and a creep of first-order lags; gpi: plays, then a saturating "
        "output function (needs --plays N); preisach: a discrete Preisach model",
    )
    p.add_argument(
        "--lags",
        type=lags_list,
        default=None,
        metavar="K[,K...]",
        help="creep lag counts tried (default 1,2,3); one number fixes it",
    )
    p.add_argument(
        "--time-constants",
        type=float_list,
        default=None,
        metavar="T1[,T2...]",
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
    p.add_argument(
        "--criterion",
        choices=CRITERIA,
        default=None,
        help="how --plays auto chooses: holdout (default) or bic (with --model pi)",
    )
    p.add_argument(
        "--initial-states",
        type=finite_float,
        default=None,
        metavar="X",
        help="the plays' state before each record (default: each record's first input)",
    )
    p.add_argument("--fit-initial-states", action="store_true", help="fit the initial states as well")
    p.add_argument(
        "--signed-weights",
        action="store_true",
        help="allow negative weights (the default allows them only for a loop that runs clockwise)",
    )
    p.add_argument("--max-threshold", type=positive_float, help="upper bound on every threshold (u units)")
    p.add_argument("--max-steps", type=positive_int, default=100, help="solver steps (default 100)")
    p.add_argument(
        "--fit-from",
        type=finite_float,
        metavar="T",
        help="fit only the samples at time >= T (earlier ones still drive the plays)",
    )
    fit_saturating.add_arguments(p)
    add_record_options(p)
    add_spike_option(p)
    add_output_options(p, "piest-fit")


# `identify` names its options as `name` in its messages; here they read as the options typed.
_OPTIONS = {
    "signed weights (`positive_weights` False)": "--signed-weights",
    **{
        f"`{name}`": "--" + name.replace("_", "-")
        for name in (
            "candidates",
            "criterion",
            "fit_from",
            "fit_initial_states",
            "initial_states",
            "lags",
            "model",
            "plays",
            "time_constants",
            "terms",
            "grid",
            "smoothness",
            "solver",
            "starts",
            "max_threshold",
            "max_steps",
        )
    },
}


def _as_options(e: ValueError) -> CLIError:
    text = str(e)
    for name, option in _OPTIONS.items():
        text = text.replace(name, option)
    return CLIError(text)


def run(args) -> int:
    import jax

    options = dict(
        model=args.model,
        plays=args.plays,
        lags=args.lags,
        time_constants=args.time_constants,
        candidates=args.candidates,
        criterion=args.criterion,
        initial_states=args.initial_states,
        fit_initial_states=args.fit_initial_states,
    )
    others = dict(
        terms=args.terms,
        grid=args.grid,
        smoothness=args.smoothness,
        solver=args.solver,
        starts=args.starts,
        positive_weights=False if args.signed_weights else None,
        max_threshold=args.max_threshold,
        max_steps=args.max_steps,
    )
    try:
        check_options(**options, **others)
    except ValueError as e:
        raise _as_options(e) from None
    if args.model in SATURATING:
        if args.model == "preisach" and args.seed != 0:
            raise CLIError("--seed does not apply to --model preisach; leave it out")
        out = _io.check_outputs(args.out, OUTPUTS if args.validate else OUTPUTS[:3], args.force)
        rec = read_record(args.data, args)
        val = read_record(args.validate, args, validation=True) if args.validate else None
        try:
            fit_mask(rec, args.fit_from)
        except ValueError as e:
            raise _as_options(e) from None
        return fit_saturating.run(args, rec, val, out, {**options, **others, "quiet": args.quiet})
    names = OUTPUTS if args.validate else OUTPUTS[:3]
    out = _io.check_outputs(args.out, names, args.force)
    rec = read_record(args.data, args)
    val = read_record(args.validate, args, validation=True) if args.validate else None
    try:
        p = plan(rec, fit_from=args.fit_from, **options)
    except ValueError as e:
        raise _as_options(e) from None
    memory.require(
        memory.fit_bytes(
            rec.n_samples, args.starts, p.n_parameters, chunked_past=LONG_RECORD if args.solver == "lm" else None
        ),
        f"--starts {args.starts} on {args.data} ({rec.n_samples} samples, up to {p.n_parameters} parameters)",
        "use fewer --starts, fewer plays or a shorter record",
    )
    result = identify(
        rec,
        val,
        **options,
        fit_from=args.fit_from,
        solver=args.solver,
        key=jax.random.key(args.seed),
        starts=args.starts,
        positive_weights=False if args.signed_weights else None,
        max_threshold=args.max_threshold,
        max_steps=args.max_steps,
        quiet=args.quiet,
    )
    note_loop(args, result.loop, result.positive_weights)
    if isinstance(result.fit, GPIFit | PreisachFit):  # chosen by --model auto
        return fit_saturating.write(args, result, out)
    f = result.fit
    assert isinstance(f, PIFit)  # the models that saturate are fitted by fit_saturating.run
    table = parameter_table(f)
    report = {**result.to_json(), **record_fields(rec, args)}
    note_extrapolation(args, report)
    written = [
        _io.write_json(out / "fit.json", report),
        _io.write_text(out / "fit.md", _markdown(result, table)),
        _io.save_figure(
            fit_figure(
                rec, np.asarray(f(rec.u)), title="fit", mask=result.mask, band=prediction_band(f, rec.u).interval()
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
    if not args.quiet:
        print(table, end="", file=sys.stderr)
    if f.undetermined_names:
        print(
            f"piest fit: warning: the record does not determine {', '.join(f.undetermined_names)} "
            "(standard error beyond half the parameter's scale, or free in the Jacobian's rank); "
            "predictions that depend on them are arbitrary: try fewer plays or lags",
            file=sys.stderr,
        )
    elif np.any(np.asarray(f.flagged)):
        idx = [int(i) + 1 for i in np.flatnonzero(np.asarray(f.flagged))]
        print(
            f"piest fit: note: plays {idx} are not excited by the input; their thresholds are "
            "not determined by the data",
            file=sys.stderr,
        )
    if result.validation is not None and not result.validation.starts_at_rest:
        print(
            f"piest fit: note: {args.validate} does not start at rest, so the raw "
            "validation_rmse depends on the unknown states it starts from; "
            "validation_rmse_ic estimates them",
            file=sys.stderr,
        )
    if not report["invertible"]:
        print(
            f"piest fit: note: the model has no stable inverse for `piest compensate`: {report['inverse_problem']}",
            file=sys.stderr,
        )
    for path in written:
        print(path)
    return 0


def _markdown(result, table) -> str:
    f = result.fit
    lines = [
        f"# piest fit: {result.record.source}",
        "",
        f"{f.model().structure}, {f.n_plays} plays, {f.n_lags} lag{'' if f.n_lags == 1 else 's'}; "
        f"RMSE {float(f.rmse):.4g}; standard errors: {f.covariance_method}.",
        "",
        table,
    ]
    if f.undetermined_names:
        lines += [f"Undetermined by the record: {', '.join(f.undetermined_names)}.", ""]
    return "\n".join(lines)
