"""`piest diagnose`: find where a PI model and the data disagree, name the missing effects."""

from .. import _parameter_table as _table
from .._diagnosis.effects import EFFECT, EFFECTS, RECORD_SPECIFIC
from .._diagnosis.figure import diagnosis_figure
from .._report import json_text
from . import memory
from . import output as _io
from ._common import (
    CLIError,
    add_output_options,
    add_record_options,
    add_spike_option,
    note_loop,
    note_outside,
    read_record,
    record_fields,
)

NAME = "diagnose"
DESCRIPTION = """\
Fit a plain PI model (16 plays on a threshold grid, positive weights, output offset, relaxed
initial states; signed weights when the loop runs clockwise, as an inverse PI's does) to
DATA.csv (columns t, u, y), locate where the residual is structured, then try
each effect (listed below) and name it only when it wins clearly on held-out blocks against the
noise floor; repeat on what remains. Both the plain and the final model are then refined jointly (weights and
every effect's parameters) by optimistix least squares (--solver). A progress bar over the
candidates shows on a terminal (not with --quiet or --json). With --json it prints the report
(the text of report.json) instead of the paths. Writes
  DIR/report.json  effects (in order), baseline_rmse, final_rmse, noise_std_estimate,
                   candidates (first-round held-out scores), parameters (of the named
                   effects), uncertainty (their values and std errors by name, and the
                   offset's; undetermined names), refinement (solver result, steps, RMSE before/after,
                   which fit was kept), rounds, where (located disagreements),
                   transferable_effects (functions of the input) and
                   record_specific_effects ({record_specific}: tied to
                   this record), and with --validate: validation {baseline_rmse,
                   final_rmse} (raw: the models from rest, transferable effects
                   only), {baseline,final}_rmse_ic (offset, play and creep initial
                   states estimated on VAL.csv, nothing else), fit percentages,
                   outside_input_range (the fraction of VAL.csv's samples whose input
                   lies outside DATA.csv's range) and inside_input_range (the four
                   RMSEs over the samples inside it)
  DIR/report.png   residuals and loops, before and after
  DIR/report.md    a short written report

effects:
{effects}

example:  piest diagnose run1.csv --validate run2.csv --out diag""".replace(
    "{record_specific}", ", ".join(RECORD_SPECIFIC)
).replace(
    "{effects}",
    "\n".join(
        f"  {e.name:<16} {e.summary}" + (" (record-specific)" if e.record_specific else "") for e in EFFECT.values()
    ),
)

OUTPUTS = ("report.json", "report.png", "report.md")


def add_arguments(p):
    p.add_argument("data", metavar="DATA.csv", help="the identification record (t, u, y)")
    p.add_argument("--validate", metavar="VAL.csv", help="a second record to evaluate both models on")
    p.add_argument("--max-effects", type=int, default=3, help="name at most this many (default 3)")
    p.add_argument(
        "--candidates",
        metavar="NAMES",
        default=",".join(EFFECTS),
        help=f"comma-separated effects to try (default: all {len(EFFECTS)})",
    )
    p.add_argument(
        "--solver",
        choices=("lm", "gn", "bfgs", "none"),
        default="lm",
        help="optimistix solver for the final joint refinement of both models: lm "
        "(Levenberg-Marquardt, default), gn (Gauss-Newton), bfgs, or none to keep the grid fit",
    )
    p.add_argument(
        "--json",
        action="store_true",
        help="print the report (report.json's text) instead of the paths written",
    )
    add_record_options(p)
    add_spike_option(p)
    add_output_options(p, "piest-diagnose")


def run(args) -> int:
    from .._diagnosis.diagnose import check_record, diagnose

    cands = [c.strip() for c in args.candidates.split(",") if c.strip()]
    bad = [c for c in cands if c not in EFFECTS]
    if bad or not cands:
        raise CLIError(
            f"--candidates: unknown effect {bad[0]!r} (choose from {', '.join(EFFECTS)})"
            if bad
            else "--candidates: give at least one effect"
        )
    if args.max_effects < 1:
        raise CLIError(f"--max-effects must be at least 1, got {args.max_effects}")
    out = _io.check_outputs(args.out, OUTPUTS, args.force)
    rec = read_record(args.data, args)
    val = read_record(args.validate, args, validation=True) if args.validate else None
    # Refuse unusable records before the (long) search, not after it.
    n = rec.n_samples + (0 if val is None else val.n_samples)
    memory.require(
        memory.diagnose_bytes(n),
        f"{args.data}{' and ' + args.validate if val else ''} ({n} samples)",
        "diagnose a shorter part of the record (a few periods suffice)",
    )
    check_record(rec)
    if val is not None:
        check_record(val, validation=True)
    diagnosis = diagnose(
        rec,
        val,
        max_effects=args.max_effects,
        candidates=cands,
        solver=None if args.solver == "none" else args.solver,
        quiet=args.quiet or args.json,
    )
    note_loop(args, diagnosis.loop, False)
    v = diagnosis.validation
    if v is not None:
        inside = {f"final_{k}": v.inside_input_range[f"final_{k}"] for k in ("rmse", "rmse_ic")}
        note_outside(args, v.outside_input_range, (float(rec.u.min()), float(rec.u.max())), inside)
    rep = _report(diagnosis, args)
    fig = diagnosis_figure(diagnosis)
    written = [_io.write_json(out / "report.json", rep)]
    written.append(_io.save_figure(fig, out / "report.png", dpi=110))
    written.append(_io.write_text(out / "report.md", _markdown(diagnosis, args.data)))
    if args.json:
        # write_json has refused any non-finite value the command does not allow, so this text
        # is report.json's.
        print(json_text(rep, name="report.json"), end="")
    else:
        print("\n".join(str(p) for p in written))
    return 0


def _report(diagnosis, args) -> dict:
    """report.json: the diagnosis's `to_json()` and where its records came from."""
    rep = diagnosis.to_json()
    rep["data"] = str(args.data)
    rep.update(record_fields(diagnosis.record, args))
    if diagnosis.validation is not None:
        rep["validation"]["data"] = str(args.validate)
    return rep


def _markdown(d, data):
    """report.md: the diagnosis `d` of the record read from `data`, in words and tables."""
    eff = ", ".join(f"`{e}`" for e in d.effects) or "none"
    lines = [
        f"# Diagnosis of {data}",
        "",
        f"Effects named, in order: {eff}.",
        "",
        *(
            [
                f"**The loop runs clockwise** (the output leads the input, as an inverse PI does; score "
                f"{d.loop.score:.0f}). Non-negative play weights shape counterclockwise loops only, so "
                "every model here, the plain PI one included, takes signed play weights, as `piest fit` does.",
                "",
            ]
            if d.loop is not None and d.loop.direction == "clockwise"
            else []
        ),
        f"Noise floor (robust std of the noise in the final residual, up to the input's short time scale): "
        f"{d.noise_std_estimate:.4g}.",
        "",
        "| | plain PI | with the named effects |",
        "|---|---|---|",
        f"| RMSE, whole record | {d.baseline_rmse:.4g} | {d.final_rmse:.4g} |",
    ]
    lines.append(f"| RMSE, held-out blocks | {d.heldout_baseline_rmse:.4g} | {d.heldout_final_rmse:.4g} |")
    v = d.validation
    if v is not None:
        lines.append(f"| RMSE, validation record | {v.baseline_rmse:.4g} | {v.final_rmse:.4g} |")
        lines.append(
            f"| RMSE, validation record, mean residual removed | "
            f"{v.baseline_rmse_offset_removed:.4g} | {v.final_rmse_offset_removed:.4g} |"
        )
        lines.append(
            f"| RMSE, validation record, initial conditions estimated | "
            f"{v.baseline_rmse_ic:.4g} | {v.final_rmse_ic:.4g} |"
        )
        lines.append(
            f"| fit %, validation record (raw / initial conditions estimated) | "
            f"{v.baseline_fit_percent:.1f} / {v.baseline_fit_percent_ic:.1f} | "
            f"{v.final_fit_percent:.1f} / {v.final_fit_percent_ic:.1f} |"
        )
        if 0 < v.outside_input_range < 1:
            inside = v.inside_input_range
            lines.append(
                f"| RMSE, validation record, inputs inside the identified range (raw / initial conditions estimated) | "
                f"{inside['baseline_rmse']:.4g} / {inside['baseline_rmse_ic']:.4g} | "
                f"{inside['final_rmse']:.4g} / {inside['final_rmse_ic']:.4g} |"
            )
    if d.record_specific_effects:
        lines += [
            "",
            "Tied to this record, left out on another: "
            + ", ".join(f"`{e}`" for e in d.record_specific_effects)
            + ". They explain this record's unrecorded past or its drift over time; another run "
            "of the device has its own, so the model used on the validation record and for "
            "compensation keeps only the effects driven by the input"
            + (": " + ", ".join(f"`{e}`" for e in d.transferable_effects) if d.transferable_effects else " (none here)")
            + ".",
            "",
        ]
    if v is not None:
        lines += [
            "",
            "On the validation record, *raw* runs the model from rest; *initial conditions "
            "estimated* fits only the output offset and the plays' and creep lags' initial "
            "states to that record (as system identification tools compare a model with data), "
            "everything else fixed.",
            "",
        ]
        if v.outside_input_range > 0:
            lo, hi = float(d.record.u.min()), float(d.record.u.max())
            lines += [
                f"{100 * v.outside_input_range:.3g} % of the validation record's samples have inputs "
                f"outside the identification record's input range ({lo:.4g} to {hi:.4g}); there every "
                "term extrapolates"
                + (
                    ", so the row of inputs inside that range is the fairer comparison."
                    if v.outside_input_range < 1
                    else "."
                ),
                "",
            ]
    for e, par in d.parameters.items():
        if par:
            lines.append(f"- `{e}`: " + ", ".join(f"{k} = {_short(x)}" for k, x in par.items()))
    if d.uncertainty is not None:
        u = d.uncertainty
        lines += [
            "",
            f"Standard errors ({u['method']}, from the final model's Jacobian on {u['samples']} samples):",
            "",
            _table.HEADER,
        ]
        for n, x in u["values"].items():
            lines.append(_table.row(n, x, u["std_errors"][n], undetermined=n in u["undetermined"]))
    lines += ["", "## Rounds (held-out RMSE per candidate; score = penalised gain / noise variance)", ""]
    for i, r in enumerate(d.rounds):
        lines.append(
            f"Round {i + 1}: current held-out RMSE {r['current_heldout_rmse']:.4g}; best "
            f"`{r['best']}` ({'named' if r['named'] else 'not significant'})."
        )
        lines.append("")
        lines.append("| candidate | held-out RMSE | score | significant |")
        lines.append("|---|---|---|---|")
        for k, c in sorted(r["candidates"].items(), key=lambda kv: -kv[1]["score"]):
            lines.append(f"| {k} | {c['heldout_rmse']:.4g} | {c['score']:.3g} | {c['significant']} |")
        lines.append("")
        for k, why in r.get("untried", {}).items():
            lines += [f"Not tried: `{k}`: {why}.", ""]
    lines += ["## Where the plain PI model disagrees with the data", ""]
    for w in d.where:
        if not w["structured"]:
            continue
        if w["kind"] == "correlation":
            lines.append(f"- residual correlates with {w['name']}: r = {w['correlation']:.2f}")
        else:
            lines.append(f"- {w['kind']} {w['name']}: RMS {w['rms']:.3g} = {w['ratio_to_noise']:.1f}x the noise floor")
    if not any(w["structured"] for w in d.where):
        lines.append("- nowhere: the residual is at the noise floor")
    return "\n".join(lines) + "\n"


def _short(x) -> str:
    """A parameter for report.md: numbers to four digits, lists of them likewise."""
    if isinstance(x, float):
        return f"{x:.4g}"
    if isinstance(x, list | tuple) and x and all(isinstance(v, float) for v in x):
        return "[" + ", ".join(f"{v:.4g}" for v in x) + "]"
    return str(x)
