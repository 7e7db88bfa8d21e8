"""What every `piest` command shares: errors, output folders, common options."""

import argparse
import sys

import numpy as np


class CLIError(Exception):
    """A problem with the user's request: printed as one line, exit code 2."""


def add_output_options(p: argparse.ArgumentParser, default_out: str) -> None:
    p.add_argument(
        "--out",
        default=default_out,
        type=out_dir,
        metavar="DIR",
        help=f"folder for the results (default: {default_out}); created if missing",
    )
    p.add_argument(
        "--force",
        action="store_true",
        help="replace results already in --out (files this command wrote there before and does "
        "not write this time are removed, so the folder holds one run)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress bars; print only the paths written")


# Counts beyond this overflow 32-bit indices (and every memory); seeds are 63-bit.
MAX_COUNT = 2**31 - 1
MAX_SEED = 2**63 - 1


def out_dir(text: str) -> str:
    if not text.strip():
        raise argparse.ArgumentTypeError("expected a folder name, got an empty one")
    return text


def _whole(text: str) -> int:
    # Digits only (int() would take `1_000` and other scripts' digits), at most 30 of them.
    body = text.strip().removeprefix("-").removeprefix("+")
    if not (body.isascii() and body.isdigit()) or len(body) > 30:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}")
    return int(text)


def positive_int(text: str) -> int:
    v = _whole(text)
    if v <= 0:
        raise argparse.ArgumentTypeError(f"must be positive, got {v}")
    if v > MAX_COUNT:
        raise argparse.ArgumentTypeError(f"must be at most {MAX_COUNT}, got {v}")
    return v


def seed(text: str) -> int:
    v = _whole(text)
    if not 0 <= v <= MAX_SEED:
        raise argparse.ArgumentTypeError(f"a seed is a whole number from 0 to 2^63 - 1, got {text}")
    return v


def _number(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None


def finite_float(text: str) -> float:
    v = _number(text)
    if v != v or v in (float("inf"), float("-inf")):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text}")
    return v


def positive_float(text: str) -> float:
    v = _number(text)
    if not v > 0 or v == float("inf"):
        raise argparse.ArgumentTypeError(f"must be a positive finite number, got {text}")
    return v


def float_list(text: str) -> list[float]:
    try:
        vals = [float(s) for s in text.replace(" ", "").split(",") if s]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers such as 0,1.5,3, got {text!r}") from None
    if not vals:
        raise argparse.ArgumentTypeError("expected at least one number")
    if any(v != v or v in (float("inf"), float("-inf")) for v in vals):
        raise argparse.ArgumentTypeError(f"NaN or inf in {text!r}")
    return vals


def columns_arg(count, example: str):
    """A parser of `count` (an int, or a tuple of the counts allowed) distinct comma-separated
    column names, matched as the loader does."""
    counts = (count,) if isinstance(count, int) else tuple(count)
    how_many = " or ".join(str(c) for c in sorted(counts))

    def parse(text: str) -> tuple[str, ...]:
        from .._data.columns import base_name

        names = tuple(c.strip() for c in text.split(","))
        if len(names) not in counts or not all(names) or len({base_name(n) for n in names}) != len(names):
            raise argparse.ArgumentTypeError(
                f"expected {how_many} distinct column names such as {example}, got {text!r}"
            )
        return names

    return parse


def add_record_options(p: argparse.ArgumentParser) -> None:
    """--columns, --resample and --segment, for every command that reads a (t, u, y) record."""
    p.add_argument(
        "--columns",
        type=columns_arg((3, 2), "time_s,voltage_V,displacement_um or H,B"),
        metavar="[TIME,]INPUT,OUTPUT",
        help="the data file's names of its time, input and output columns (default t,u,y, or "
        "columns whose leading words are time, input/voltage and output/displacement; names match "
        "without case or a unit in brackets: `t [s]` is t); two names for data without time, whose "
        "samples are then counted (step 1)",
    )
    p.add_argument("--resample", action="store_true", help="interpolate non-uniform time onto a uniform grid")
    p.add_argument(
        "--max-gap",
        type=positive_float,
        metavar="SECONDS",
        help="with --resample, the longest gap in time it fills (default 10 median steps; longer ones are refused)",
    )
    p.add_argument(
        "--segment",
        type=finite_float,
        metavar="LABEL",
        help="of a record with a `segment` column (several loops or reversal curves), use the segment with this "
        "label (default: all of them, one after another in the file's order)",
    )


def model_plays(model) -> int:
    """How many plays a model file's model runs: its PI part's, or a Preisach model's."""
    pi = getattr(model, "pi", None)
    return pi.n_plays if pi is not None else model.shape[0]


def check_creep_sampling(model, t, what: str) -> None:
    """Refuse a signal `what` sampled at another interval than the one a model's creep was
    identified at (its time constants count in that interval's samples)."""
    creep = getattr(model, "creep", None)
    if creep is None or len(t) < 2:
        return
    dt = float(np.median(np.diff(t)))
    if not np.isclose(dt, creep.dt, rtol=1e-3):
        raise CLIError(
            f"{what} is sampled every {dt:g}, but the model's creep was identified at dt = {creep.dt:g}; "
            f"sample it every {creep.dt:g}"
        )


def add_spike_option(p: argparse.ArgumentParser) -> None:
    """--spikes, for the commands that fit a record's output."""
    p.add_argument(
        "--spikes",
        choices=["refuse", "drop", "keep"],
        default="refuse",
        help="isolated spikes in the output (one sample far from both neighbours, a sensor glitch): "
        "refuse the record naming them (default), drop them (each replaced by its neighbours' mean) "
        "or keep them as measured",
    )


def _spikes(rec, path, args):
    """The record with its output's isolated spikes handled as --spikes asks."""
    import dataclasses

    from .._data.spikes import isolated_spikes, without_spikes

    rows = isolated_spikes(rec.y)
    if rows.size == 0:
        return rec
    shown = ", ".join(f"t = {rec.t[i]:.6g} (sample {i}, y = {rec.y[i]:.6g})" for i in rows[:3])
    more = f" and {rows.size - 3} more" if rows.size > 3 else ""
    what = f"{rows.size} isolated spike{'s' if rows.size > 1 else ''} in the output at {shown}{more}"
    if args.spikes == "refuse":
        raise CLIError(
            f"{path}: {what}: each far from both neighbours, which agree (a sensor glitch); "
            "--spikes drop replaces each by its neighbours' mean, --spikes keep fits them as measured"
        )
    if args.spikes == "drop":
        note(args, f"{path}: {what}, each replaced by its neighbours' mean (--spikes drop)")
        return dataclasses.replace(rec, y=without_spikes(rec.y, rows))
    note(args, f"{path}: {what}, fitted as measured (--spikes keep)")
    return rec


def read_record(path, args, *, validation: bool = False):
    """The record `path` as the options of `add_record_options` ask: one segment of it, or all
    of its segments joined, and a note on stderr when its time counts samples.

    **Arguments:** `path`, the data file; `args`, the parsed options; `validation`, the file is
    a `--validate` record, to which `--segment` (a label of the data file) does not apply.

    **Returns:** the [`Record`][piest_jax.Record]. A record of several segments without
    `--segment` is [joined][piest_jax.Record.joined] (the plays' memory runs on from each
    segment into the next), with a note that says so.
    """
    from .._data.record import load_record

    if args.max_gap is not None and not args.resample:
        raise CLIError("--max-gap is only used with --resample")
    rec = load_record(path, resample=args.resample, max_gap=args.max_gap, columns=args.columns)
    if args.segment is not None and not validation:
        rec = rec.select_segment(args.segment)
    elif rec.n_segments > 1:
        rec = rec.joined()
        choose = "" if validation else "; --segment LABEL takes one of them"
        note(
            args,
            f"{path} holds {rec.n_segments} segments, taken one after another in the file's order: "
            "the plays' memory runs on from each into the next, as when they were measured in "
            f"sequence (reversal curves, loops of growing amplitude){choose}",
        )
    if rec.time_is_index:
        note_sample_time(args, path)
    if getattr(args, "spikes", None) is not None:
        rec = _spikes(rec, path, args)
    return rec


def note_sample_time(args, path) -> None:
    """The note for a record whose time counts samples."""
    note(
        args,
        f"{path} has no time in seconds: t counts samples (step 1), so the times, "
        "time constants and rates in the results are in samples",
    )


def record_fields(rec, args) -> dict:
    """What a command's JSON says of how its record was read: `time_unit` "sample" when the
    time counts samples, the `segment` chosen with --segment, `segments_joined` (how many) when
    all of a record's segments were taken one after another; nothing for an ordinary record."""
    fields: dict = {"time_unit": "sample"} if rec.time_is_index else {}
    if getattr(args, "segment", None) is not None:
        fields["segment"] = args.segment
    elif rec.n_segments > 1:
        fields["segments_joined"] = rec.n_segments
    return fields


def note(args, text: str) -> None:
    """A note for stderr, printed once the command has succeeded (an error stays one line)."""
    args.__dict__.setdefault("_notes", []).append(text)


def note_loop(args, loop, positive_weights: bool) -> None:
    """Say when the record's loop runs clockwise, and what the fit did about it."""
    if loop is None or loop.direction != "clockwise":
        return
    what = (
        "fitted with signed weights, which can shape it"
        if not positive_weights
        else "non-negative weights cannot shape it, and this model takes no other"
    )
    note(
        args,
        f"the loop runs clockwise (the output leads the input, as an inverse PI does; score {loop.score:.0f}): {what}",
    )


def note_extrapolation(args, report: dict) -> None:
    """Say when the validation record's input leaves the range the model was identified on,
    from fit.json's keys (`validation_outside_input_range`, `input_range`,
    `validation_inside_input_range`)."""
    if "validation_outside_input_range" in report:
        inside = {f"validation_{k}": v for k, v in report["validation_inside_input_range"].items()}
        note_outside(args, report["validation_outside_input_range"], report["input_range"], inside)


def note_outside(args, share: float, identified_range, inside: dict) -> None:
    """The note for a validation record with a `share` of its samples' inputs outside
    `identified_range` (min, max); `inside` names the RMSEs over the samples inside it."""
    if not share > 0:
        return
    lo, hi = identified_range
    where = " and ".join(f"{k} {v:.4g}" for k, v in inside.items() if v is not None)
    note(
        args,
        f"{100 * share:.3g} % of {args.validate}'s samples have inputs outside the identification "
        f"record's input range ({lo:.4g} to {hi:.4g}), where the model extrapolates"
        + (f"; over the samples inside it: {where}" if where else ""),
    )


def print_notes(args) -> None:
    """The notes `note` kept, one line each."""
    for text in getattr(args, "_notes", ()):
        print(f"piest {args.command}: note: {text}", file=sys.stderr)
