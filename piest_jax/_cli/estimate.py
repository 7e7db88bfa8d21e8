"""`piest estimate`: the paper's online estimators on a measured record, streamed in chunks."""

import numpy as np

from .._estimation.online_figure import online_estimate_figure
from . import memory
from . import output as _io
from ._common import (
    CLIError,
    add_output_options,
    add_record_options,
    float_list,
    note_sample_time,
    positive_float,
    positive_int,
    read_record,
    record_fields,
)

NAME = "estimate"
DESCRIPTION = """\
Run an online estimator over DATA.csv (columns t, u, y) with a fixed play bank: thresholds from
--thresholds, from a fitted model (--from-fit fit.json, its thresholds and initial states), or
--plays uniform thresholds on [0, half the input's range) by default. The output offset is
estimated as one more weight (--no-offset to leave it out). The record is streamed in chunks:
memory does not grow with its length (a CSV over 32 MB of plain rows is read again in chunks for
each pass, never whole). Estimation starts once the input has visited both ends of
its range (--start auto), when the plays no longer depend on their unknown states before the
record began; --start 0 or a time in seconds overrides that. Writes
  DIR/estimate.json  thresholds, initial_states (at the start), weights_final, offset_final,
                     final_rmse (RMSE from the start to the end of the model with the final
                     weights), estimator and settings, trajectory (t, weights, offset,
                     error_rms at 2000 instants), pe (per window: start time, PE level of the
                     normalised regressor, exciting), certificate (ContinuousRLS: bound on the
                     relative weight error at the end of every window)
  DIR/estimate.png   weights over time, prediction error, PE level per window, certificate

estimators:  rls         the paper's continuous-time RLS (eqs. 5-6), --P0, --normalisation
             forgetting  discrete RLS with forgetting factor --forgetting (1 = least squares)
             gradient    normalised gradient with --gain
example:  piest estimate run.csv --plays 20 --out est"""

OUTPUTS = ("estimate.json", "estimate.png")
ESTIMATORS = ("rls", "forgetting", "gradient")


def _start(text: str):
    if text == "auto":
        return text
    try:
        v = float(text)
    except ValueError:
        raise CLIError(f"--start: expected 'auto' or a time in seconds, got {text!r}") from None
    if not (v >= 0 and np.isfinite(v)):
        raise CLIError(f"--start must be a time >= 0 in seconds, got {text}")
    return v


def add_arguments(p):
    p.add_argument("data", metavar="DATA.csv", help="the record (t, u, y)")
    src = p.add_mutually_exclusive_group()
    src.add_argument("--thresholds", type=float_list, metavar="R1,R2,...", help="play thresholds")
    src.add_argument("--from-fit", metavar="FIT.json", help="thresholds and initial states of a `piest fit` model")
    src.add_argument("--plays", type=positive_int, default=20, help="uniform thresholds (default 20)")
    p.add_argument("--estimator", choices=ESTIMATORS, default="rls", help="default: rls (the paper's)")
    p.add_argument(
        "--P0",
        type=positive_float,
        default=None,
        help="initial gain P0·I, for data scaled to magnitude one (default 1e8)",
    )
    p.add_argument(
        "--normalisation",
        choices=("paper", "standard"),
        default=None,
        help="rls: paper (m = 1 + h'h, divide by m^2; default) or standard (m^2 = 1 + h'h)",
    )
    p.add_argument("--forgetting", type=positive_float, default=None, help="forgetting factor in (0, 1] (default 1)")
    p.add_argument("--gain", type=positive_float, default=None, help="gradient gain (default 1)")
    p.add_argument("--no-offset", action="store_true", help="do not estimate an output offset")
    p.add_argument("--start", type=str, default="auto", help="'auto' (default), or a time in seconds")
    p.add_argument(
        "--window",
        type=positive_float,
        metavar="SECONDS",
        help="PE window length (default: a tenth of the estimated part)",
    )
    add_record_options(p)
    add_output_options(p, "piest-estimate")


def _thresholds(args, rec):
    if args.thresholds is not None:
        r = np.asarray(args.thresholds, float)
        if r[0] != 0 or np.any(np.diff(r) <= 0):
            raise CLIError("--thresholds must start at 0 and increase strictly, e.g. 0,1,2")
        return r, None
    if args.from_fit is not None:
        from .._identification.model_file import load_model

        try:
            model = load_model(args.from_fit)
        except ValueError as e:
            raise CLIError(f"--from-fit: {' '.join(str(e).split())}") from None
        pi = getattr(model, "pi", None)
        if pi is None:
            raise CLIError(f"--from-fit {args.from_fit}: a {model.structure} model has no PI thresholds to estimate")
        return np.asarray(pi.thresholds, float), np.asarray(pi.initial_states, float)
    half = 0.5 * (rec.u_max - rec.u_min)
    return np.arange(args.plays) * half / args.plays, None


class _Record:
    """What this command reads of its record, read whole or as a stream: `source` (the arguments
    `estimate_record` takes for it), `held` (samples held in memory) and the record's facts."""

    def __init__(self, args):
        stream = _stream(args)
        if stream is None:
            rec = read_record(args.data, args)
            self.source, self.held, self.t0 = (rec.u, rec.y), rec.n_samples, float(rec.t[0])
            self.u_min, self.u_max = float(np.min(rec.u)), float(np.max(rec.u))
        else:
            if stream.time_is_index:
                note_sample_time(args, args.data)
            rec = stream
            self.source, self.held, self.t0 = (stream, None), 0, stream.t0
            self.u_min, self.u_max = stream.u_min, stream.u_max
        self.dt, self.n_samples, self.time_is_index = rec.dt, rec.n_samples, rec.time_is_index
        # A file with a `segment` column is read whole, never streamed.
        self.n_segments = rec.n_segments if stream is None else 1


def _stream(args):
    """The record as a stream when it is a large plain CSV (read again in chunks for each pass,
    so memory does not grow with it), else None (read whole, as every command reads it)."""
    from pathlib import Path

    from .._data.record import STREAM_BYTES
    from .._data.stream import open_record_stream

    path = Path(args.data)
    if args.resample or args.segment is not None or not path.is_file() or path.stat().st_size <= STREAM_BYTES:
        return None
    return open_record_stream(path, columns=args.columns)


def run(args) -> int:
    import piest_jax as pj

    from .._estimation.online import estimate_record, settled_start

    # Each setting belongs to some estimators; one given to another would be ignored.
    used = {
        "P0": ("rls", "forgetting"),
        "normalisation": ("rls",),
        "forgetting": ("forgetting",),
        "gain": ("gradient",),
    }
    for name, estimators in used.items():
        if getattr(args, name) is not None and args.estimator not in estimators:
            raise CLIError(
                f"--{name} is a setting of --estimator {' or '.join(estimators)}, not of --estimator {args.estimator}"
            )
    defaults = {"P0": 1e8, "normalisation": "paper", "forgetting": 1.0, "gain": 1.0}
    for name, value in defaults.items():
        if getattr(args, name) is None:
            setattr(args, name, value)
    if args.forgetting > 1:
        raise CLIError(f"--forgetting must be in (0, 1], got {args.forgetting}")
    start = _start(args.start)
    out = _io.check_outputs(args.out, OUTPUTS, args.force)
    rec = _Record(args)
    r, x0 = _thresholds(args, rec)
    est: pj.AbstractEstimator
    if args.estimator == "rls":
        est = pj.ContinuousRLS(args.P0, rec.dt, normalisation=args.normalisation)
        settings = dict(P0=args.P0, dt=rec.dt, normalisation=args.normalisation)
    elif args.estimator == "forgetting":
        est = pj.ForgettingRLS(args.P0, args.forgetting)
        settings = dict(P0=args.P0, forgetting=args.forgetting)
    else:
        est = pj.NormalisedGradient(args.gain)
        settings = dict(gain=args.gain)
    t0 = rec.t0
    k0 = settled_start(rec.source[0]) if start == "auto" else int(round((start - t0) / rec.dt))
    if not 0 <= k0 <= rec.n_samples - 2:
        raise CLIError(f"--start {args.start} leaves fewer than 2 samples of the record")
    window = None if args.window is None else int(round(args.window / rec.dt))
    if window is not None and not 2 <= window <= rec.n_samples - k0:
        raise CLIError(f"--window {args.window} s is not between 2 samples and the estimated part of the record")
    from .._estimation.online import DEFAULT_CHUNK

    m = len(r) + (not args.no_offset)
    block = min(rec.n_samples, DEFAULT_CHUNK)  # a chunk holds whole windows or part of one
    memory.require(
        memory.rls_bytes(m, rec.held) + memory.bank_bytes(block, m),
        f"{m} weights ({len(r)} plays) on {args.data}",
        "use fewer plays",
    )
    res = estimate_record(
        est, *rec.source, r, dt=rec.dt, initial_states=x0, offset=not args.no_offset, window=window, start=k0
    )
    report = dict(
        data=str(args.data),
        estimator=args.estimator,
        settings=settings,
        offset_estimated=not args.no_offset,
        **res.to_json(t0),
        **record_fields(rec, args),
    )
    written = [_io.write_json(out / "estimate.json", report)]
    fig = online_estimate_figure(res, title=args.estimator, t0=t0)
    written.append(_io.save_figure(fig, out / "estimate.png", dpi=110))
    print("\n".join(str(p) for p in written))
    return 0
