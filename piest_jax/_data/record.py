"""Loading measured (t, u, y) records from CSV or NPZ, with errors that name the file and row."""

import dataclasses
from importlib import resources
from pathlib import Path
from typing import NoReturn

import numpy as np

from .columns import INDEX_NAMES, SEGMENT, base_name, by_role, column_names, to_number

MIN_SAMPLES = 8
_DELIMITERS = (",", ";", "\t")
_HEADER_SEARCH_LINES = 200
# What a refusal of the default columns adds.
COLUMNS_HINT = "; or name the file's columns with columns= (CLI: --columns TIME,INPUT,OUTPUT)"


class DataError(ValueError):
    """A data file or array that cannot be used, with a message naming the file, row and problem.

    **Arguments:** the message (a `ValueError`'s).
    """


@dataclasses.dataclass(frozen=True)
class Record:
    """A uniformly sampled measurement: time `t`, input `u`, output `y` (all float64, (T,)).

    **Fields:**

    - `t`, `u`, `y`: the three required columns.
    - `extras`: any further columns by name (e.g. `desired`), each (T,).
    - `source`: where the record came from (a path or a description).
    - `segment`: None, or (T,) labels of the segments the record is made of (several loops or
      reversal curves measured one after another); each segment's rows are contiguous and its
      time is uniform, while time may restart between segments.
    - `time_is_index`: `t` counts samples (data without a time column, or whose time column is a
      sample index): its step is 1 and times derived from it are in samples, not seconds.
    """

    t: np.ndarray
    u: np.ndarray
    y: np.ndarray
    extras: dict = dataclasses.field(default_factory=dict)
    source: str = "<memory>"
    segment: np.ndarray | None = None
    time_is_index: bool = False

    def __post_init__(self):
        n = len(self.t)
        cols = [("u", self.u), ("y", self.y), *self.extras.items()]
        if self.segment is not None:
            cols.append((SEGMENT, self.segment))
        for name, col in cols:
            if np.shape(col) != (n,):
                raise DataError(f"{self.source}: column `{name}` has shape {np.shape(col)}, expected ({n},)")

    @property
    def n_segments(self) -> int:
        """The number of segments (1 for a record without a `segment` column)."""
        return 1 if self.segment is None else len(_segment_bounds(self.segment, self.source))

    def segments(self) -> list["Record"]:
        """The record's segments, in order, each a record of its own (one without segments:
        `[self]`)."""
        if self.segment is None:
            return [self]
        return [self.slice(a, b) for a, b in _segment_bounds(self.segment, self.source)]

    def select_segment(self, label) -> "Record":
        """The segment labelled `label` as a record of its own.

        **Arguments:** `label`, a value of the `segment` column.

        **Returns:** the [`Record`][] of its rows. Raises [`DataError`][] naming the labels there
        are when no segment has this label (or the record has no segments), and when the segment
        has fewer samples than a record needs (8).
        """
        if self.segment is None:
            _fail(self.source, f"no `{SEGMENT}` column to select segment {_label(label)} from")
        for a, b in _segment_bounds(self.segment, self.source):
            if self.segment[a] == label:
                if b - a < MIN_SAMPLES:
                    _too_short(self.source, b - a, MIN_SAMPLES, f"segment {_label(label)}")
                return self.slice(a, b)
        _fail(self.source, f"no segment labelled {_label(label)}; the labels are {_labels(self.segment)}")

    def joined(self) -> "Record":
        """The segments as one run: each follows the one before without a gap.

        Time is stamped again on one uniform grid through all segments (the sample count for a
        record whose time counts samples); the samples, their order and the segment labels are
        kept. A model run on it carries the plays' memory from each segment into the next, as
        if the input had gone straight from one segment's last sample to the next one's first:
        what the material keeps when the segments were measured one after another, as reversal
        curves (each starting where the input came down to from saturation) and loops of
        growing amplitude are. Time-driven parts of a model (creep, dynamics) see no pause at
        a boundary. A record of one segment is returned as it is.
        """
        if self.n_segments == 1:
            return self
        step = 1.0
        if not self.time_is_index:
            # The step inside the segments (the loader held them all to one).
            bounds = _segment_bounds(self.segment, self.source)
            steps = np.concatenate([np.diff(self.t[a:b]) for a, b in bounds])
            if steps.size == 0:
                _fail(self.source, "no segment has two samples, so the record states no time step to join them on")
            step = float(np.median(steps))
        t = self.t[0] + step * np.arange(self.n_samples, dtype=np.float64)
        return dataclasses.replace(self, t=t)

    @property
    def n_samples(self) -> int:
        """The number of samples T."""
        return len(self.t)

    @property
    def dt(self) -> float:
        """The sampling interval (the median step of `t`)."""
        return float(np.median(np.diff(self.t)))

    @classmethod
    def from_arrays(
        cls,
        t,
        u,
        y,
        *,
        extras: dict | None = None,
        source: str = "<arrays>",
        min_samples: int = MIN_SAMPLES,
        dt_tolerance: float = 1e-3,
        resample: bool = False,
        max_gap: float | None = None,
        segment=None,
        time_is_index: bool = False,
    ) -> "Record":
        """A record from arrays, checked as [`load_record`][] checks a file.

        **Arguments:**

        - `t`, `u`, `y`: one-dimensional sequences of equal length (time strictly increasing);
          `t` None for data without time (the sample number is used, `time_is_index` set).
        - `extras`: further columns by name, each as long as `u`.
        - `source`: the description that error messages and `Record.source` carry.
        - `min_samples`, `dt_tolerance`, `resample`, `max_gap`: as for [`load_record`][].
        - `segment`: None, or segment labels, one per sample (see [`Record`][]).
        - `time_is_index`: `t` is a sample index, not a time in seconds.

        **Returns:** a [`Record`][] of float64 copies. Raises [`DataError`][] naming the problem:
        a column that is not one-dimensional, not numeric, of another length, NaN or infinite,
        too few samples, time not strictly increasing, non-uniform sampling, a segment whose
        rows are not contiguous.
        """
        if t is None:
            t, time_is_index = np.arange(np.shape(u)[0] if np.ndim(u) else 0), True
        more = [] if segment is None else [(SEGMENT, segment)]
        cols = {}
        for name, col in [("t", t), ("u", u), ("y", y), *(extras or {}).items(), *more]:
            arr = np.asarray(col)
            if arr.ndim != 1:
                _fail(source, f"column `{name}` must be one-dimensional, got shape {arr.shape}")
            if np.issubdtype(arr.dtype, np.complexfloating) or not (
                np.issubdtype(arr.dtype, np.number) or arr.dtype == bool
            ):
                _fail(source, f"column `{name}` is not real numbers (dtype {arr.dtype})")
            cols[name] = np.array(arr, dtype=np.float64)
        n = len(cols["t"])
        for name, col in cols.items():
            if len(col) != n:
                _fail(source, f"column `{name}` has {len(col)} samples but `t` has {n}")
        t, u, y = cols.pop("t"), cols.pop("u"), cols.pop("y")
        seg = cols.pop(SEGMENT) if segment is not None else None
        opts = dict(min_samples=min_samples, dt_tolerance=dt_tolerance, resample=resample, max_gap=max_gap)
        return _record(t, u, y, cols, source, None, seg, time_is_index, **opts)

    @classmethod
    def from_dataframe(cls, df, *, columns=None, source: str = "<DataFrame>", **kwargs) -> "Record":
        """A record from a pandas `DataFrame` with columns `t`, `u`, `y` (any case, units in
        brackets ignored), chosen as [`load_record`][] chooses a file's.

        **Arguments:** `df`, the frame (further numeric columns are kept as `extras`, a
        `segment` column as the segment labels); `columns`, the frame's names of its time,
        input and output columns, as for [`load_record`][]; `source` and `kwargs` as for
        [`Record.from_arrays`][].

        **Returns:** a [`Record`][]. Raises [`DataError`][] naming missing or duplicated columns
        or any problem [`Record.from_arrays`][] finds.
        """
        names = [base_name(str(c)) for c in df.columns]
        dupes = sorted({n for n in names if names.count(n) > 1})
        if dupes:
            _fail(source, f"duplicated column name(s): {', '.join(dupes)}")
        time, un, yn = _pick(names, column_names(columns, source), source, "the frame")
        cols = {n: df[c].to_numpy() for n, c in zip(names, df.columns)}
        t = cols.pop(time) if time is not None else None
        u, y = cols.pop(un), cols.pop(yn)
        seg = cols.pop(SEGMENT, None)
        # A column of the frame named t, u or y that was not chosen would shadow the chosen one.
        extras = {k: v for k, v in cols.items() if k not in ("t", "u", "y")}
        return cls.from_arrays(
            t,
            u,
            y,
            extras=extras,
            source=source,
            segment=seg,
            time_is_index=time is None or time in INDEX_NAMES,
            **kwargs,
        )

    def slice(self, start: int | None = None, stop: int | None = None) -> "Record":
        """The samples `start:stop` as a new record (time stamps kept)."""
        sl = slice(start, stop)
        extras = {k: v[sl] for k, v in self.extras.items()}
        seg = None if self.segment is None else self.segment[sl]
        return Record(self.t[sl], self.u[sl], self.y[sl], extras, self.source, seg, self.time_is_index)


def _pick(names, given, source, where, row=None, hint=""):
    """The (time, input, output) column names among `names`, as given or by the rules of
    `columns.py`: t, u, y; or u and y with no time, or with a sample-index column."""
    if given is not None:
        missing = [n for n in given if n is not None and n not in names]
        if missing:
            _fail(source, f"missing column(s) {', '.join(missing)}: {where} has {', '.join(names)}", row)
        return given
    if {"t", "u", "y"} <= set(names):
        return "t", "u", "y"
    if {"u", "y"} & set(names) == set() and (roles := by_role(names)) is not None:
        return roles
    if {"u", "y"} <= set(names):
        others = [n for n in names if n not in ("u", "y", SEGMENT)]
        index = [n for n in others if n in INDEX_NAMES]
        if len(index) == len(others) <= 1:
            return (index[0] if index else None), "u", "y"
        _fail(
            source,
            f"no time column `t`: {where} has {', '.join(names)}; name its time, input and output "
            f"with columns= (CLI: --columns TIME,INPUT,OUTPUT), or keep only u, y, a sample index "
            f"({'/'.join(INDEX_NAMES)}) and `{SEGMENT}` for data without time",
            row,
        )
    missing = [c for c in ("t", "u", "y") if c not in names]
    _fail(source, f"missing column(s) {', '.join(missing)}: {where} has {', '.join(names)}{hint}", row)


def _segment_bounds(segment, source, rows=None):
    """(start, stop) of each run of equal labels; a label that comes back later is refused."""
    starts = np.flatnonzero(np.r_[True, segment[1:] != segment[:-1]])
    bounds = list(zip(starts.tolist(), [*starts[1:].tolist(), len(segment)]))
    seen: dict[object, int] = {}
    for a, _ in bounds:
        label = segment[a]
        if label in seen:
            _fail(
                source,
                f"segment {label:g} starts again after other segments (it began at "
                f"{_where(seen[label], rows)}); the rows of one segment must be together",
                rows[a] if rows is not None else None,
            )
        seen[label] = a
    return bounds


def _where(k, rows):
    return f"row {rows[k]}" if rows is not None else f"sample {k}"


def _label(v):
    return f"{v:g}" if isinstance(v, int | float | np.number) else repr(v)


def _labels(segment):
    labels = segment[np.r_[True, segment[1:] != segment[:-1]]]
    return ", ".join(_label(v) for v in labels)


def _fail(source, msg, row=None) -> NoReturn:
    where = f"{source}, row {row}" if row is not None else str(source)
    raise DataError(f"{where}: {msg}")


def _header_candidates(lines):
    """Each non-blank, non-comment line near the top, split on its most frequent delimiter."""
    for i, line in enumerate(lines[:_HEADER_SEARCH_LINES]):
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        delim = max(_DELIMITERS, key=stripped.count)
        yield i, delim, [base_name(c) for c in stripped.split(delim)]


def _find_header(lines, source, required=("t", "u", "y"), hint=""):
    for i, delim, names in _header_candidates(lines):
        if set(required) <= set(names):
            return i, delim, names
    first = next((ln.strip() for ln in lines if ln.strip()), None)
    if first is None:
        _fail(source, "the file is empty")
    for i, delim, names in _header_candidates(lines):
        # A row of names (not numbers) that lacks some of t, u, y is a header missing columns.
        if not any(_is_number(c) for c in names) and set(required) & set(names):
            missing = [c for c in required if c not in names]
            _fail(
                source,
                f"missing column(s) {', '.join(missing)}: the header has {', '.join(names)}{hint}",
                i + 1,
            )
    listed = ", ".join(required[:-1]) + f" and {required[-1]}" if len(required) > 1 else required[0]
    _fail(
        source,
        f"no header row naming the column{'s' * (len(required) > 1)} {listed} was found "
        f"(first line: {first[:80]!r}); a header such as `{','.join(required)}` is required{hint}",
    )


def _is_number(text):
    return to_number(text) is not None


def _parse_rows(lines, start, delim, names, source, *, trailing=False):
    ncol = len(names)
    # Line numbers (from 1) of the data rows, as one integer array: a long record costs 8 bytes a
    # row here, not a Python object per row.
    rows = np.fromiter(
        (i + 1 for i in range(start, len(lines)) if lines[i].strip() and not lines[i].lstrip().startswith("#")),
        dtype=np.int64,
    )
    if rows.size == 0:
        _fail(source, "the header is there but no data rows follow")
    usecols = range(ncol) if trailing else None
    try:
        # loadtxt skips the same blank and `#` lines as `rows` does.
        # Its parser reads what `to_number` reads: ASCII literals, quoted or not.
        data = np.loadtxt(lines[start:], delimiter=delim, ndmin=2, usecols=usecols, comments="#", quotechar='"')
        if data.shape == (rows.size, ncol):
            return data, rows
    except ValueError:
        pass
    # Slow path only to say exactly which row is wrong.
    body = [(i - 1, lines[i - 1]) for i in rows.tolist()]
    values = []
    for i, ln in body:
        cells = [c.strip() for c in ln.split("#", 1)[0].split(delim)]
        if trailing and len(cells) == ncol + 1 and not cells[-1]:
            cells.pop()
        if len(cells) != ncol:
            _fail(source, f"expected {ncol} cells as in the header, found {len(cells)}", i + 1)
        vals = []
        for j, c in enumerate(cells):
            v = to_number(c)
            if v is None:
                _fail(source, f"cell {j + 1} is not a number: {c[:40]!r} (column `{names[j]}`)", i + 1)
            vals.append(v)
        values.append(vals)
    return np.asarray(values, dtype=np.float64), [i + 1 for i, _ in body]


def _record(t, u, y, extras, source, rows, segment, time_is_index, **opts):
    """A checked [`Record`][]: each segment validated (and resampled) on its own."""
    more = {} if segment is None else {SEGMENT: segment}
    _finite({"t": t, "u": u, "y": y, **extras, **more}, source, rows)
    if segment is None:
        t, u, y, extras = _validate(t, u, y, extras, source, rows, **opts)
        return Record(t, u, y, extras, source, None, time_is_index)
    if len(t) < opts["min_samples"]:
        _too_short(source, len(t), opts["min_samples"])
    parts = []
    bounds = _segment_bounds(segment, source, rows)
    # One step for the whole record: the median over the steps inside the segments.
    steps = np.concatenate([np.diff(t[a:b]) for a, b in bounds])
    step = float(np.median(steps)) if steps.size else None
    for a, b in bounds:
        label = f"segment {segment[a]:g}"
        cut = lambda c: c[a:b]  # noqa: E731
        parts.append(
            _validate(
                cut(t),
                cut(u),
                cut(y),
                {k: cut(v) for k, v in extras.items()},
                source,
                None if rows is None else rows[a:b],
                step=step,
                part=f"{label} ({_where(a, rows)})",
                # A segment may be short (a reversal curve that starts near saturation): the
                # record as a whole holds min_samples.
                **{**opts, "min_samples": 1},
            )
        )
        parts[-1] = (*parts[-1], np.full(len(parts[-1][0]), segment[a]))
    t, u, y, seg = (np.concatenate([p[i] for p in parts]) for i in (0, 1, 2, 4))
    extras = {k: np.concatenate([p[3][k] for p in parts]) for k in extras}
    return Record(t, u, y, extras, source, seg, time_is_index)


def _too_short(source, n, min_samples, part=None) -> NoReturn:
    head = "only" if part is None else f"{part} has only"
    _fail(source, f"{head} {n} sample{'s' * (n != 1)}; at least {min_samples} are needed")


def _finite(cols, source, rows):
    for name, col in cols.items():
        bad = ~np.isfinite(col)
        if bad.any():
            k = int(np.argmax(bad))
            row = rows[k] if rows is not None else None
            _fail(source, f"column `{name}` holds {col[k]} (NaN or inf are not data)", row)


# Resampling interpolates across gaps up to this many median steps unless told otherwise.
MAX_GAP_STEPS = 10


def _validate(
    t, u, y, extras, source, rows, *, min_samples, dt_tolerance, resample, max_gap=None, step=None, part=None
):
    """Time and length checked (and resampled when asked); `step`, the step to hold time to
    (default: its median); `part`, the segment's name for messages."""
    if len(t) < min_samples:
        _too_short(source, len(t), min_samples, part)
    dt = np.diff(t)
    if np.any(dt <= 0):
        k = int(np.argmax(dt <= 0))
        row = rows[k + 1] if rows is not None else None
        what = "repeats" if dt[k] == 0 else "goes backwards"
        _fail(source, f"time is not strictly increasing: t = {float(t[k + 1]):.10g} {what}", row)
    if step is None:
        if not dt.size:  # one sample of a segment: nothing to check
            return t, u, y, extras
        step = float(np.median(dt))
    dev = np.abs(dt - step) / step
    if np.any(dev > dt_tolerance):
        if not resample:
            k = int(np.argmax(dev))
            row = rows[k + 1] if rows is not None else None
            _fail(
                source,
                f"non-uniform sampling: step {dt[k]:.6g} against the median {step:.6g} "
                f"(tolerance {dt_tolerance:g} relative); pass resample=True (CLI: --resample) "
                "to interpolate onto a uniform grid",
                row,
            )
        n = int(np.floor((t[-1] - t[0]) / step + 1e-9)) + 1
        limit = MAX_GAP_STEPS * step if max_gap is None else float(max_gap)
        if np.any(dt > limit):
            k = int(np.argmax(dt))
            row = rows[k + 1] if rows is not None else None
            said = f"max_gap {limit:.6g}" if max_gap is not None else f"{MAX_GAP_STEPS} median steps"
            _fail(
                source,
                f"a gap of {dt[k]:.6g} (t = {float(t[k]):.10g} to {float(t[k + 1]):.10g}) is too long to "
                f"resample across: longer than {said} (median step {step:.6g}), it would be filled with "
                f"{int(round(dt[k] / step)) - 1} invented samples; split the record, or allow it with "
                "max_gap (CLI: --max-gap)",
                row,
            )
        if n > 10 * len(t):
            # Interpolating across a gap this long would invent most of the record.
            k = int(np.argmax(dt))
            row = rows[k + 1] if rows is not None else None
            _fail(
                source,
                f"a gap of {dt[k]:.6g} against the median step {step:.6g} is too long to "
                f"resample across ({n} grid points from {len(t)} samples); split the record",
                row,
            )
        grid = t[0] + step * np.arange(n)
        interp = lambda c: np.interp(grid, t, c)  # noqa: E731
        return grid, interp(u), interp(y), {k: interp(v) for k, v in extras.items()}
    return t, u, y, extras


def load_record(
    path,
    *,
    min_samples: int = MIN_SAMPLES,
    dt_tolerance: float = 1e-3,
    resample: bool = False,
    max_gap: float | None = None,
    columns=None,
) -> Record:
    """Read a measured record from a CSV (header naming `t,u,y`) or an NPZ (arrays `t`, `u`, `y`).

    Lines before the header (instrument preamble) and lines starting with `#` are skipped; extra
    columns are kept in `Record.extras`. Header names match without case, quotes or a unit in
    brackets or parentheses (`t [s]` is `t`); quoted numbers are read; `1_000` and digits of
    other scripts are not numbers. Data without time (a header of `u,y` alone, or with a sample
    index such as `n`) count samples: `t` is the index, `Record.time_is_index` is set. A
    `segment` column splits the record into segments (loops, reversal curves), each checked on
    its own (see `docs/data.md`).

    **Arguments:**

    - `path`: the `.csv` or `.npz` file.
    - `min_samples`: fewer samples than this are rejected.
    - `dt_tolerance`: largest relative deviation of a time step from the median step.
    - `resample`: interpolate linearly onto a uniform grid instead of rejecting non-uniform time.
    - `max_gap`: the longest gap between samples that `resample` fills (in the time unit; default
      10 median steps); a longer one is refused, since most of what fills it would be invented.
    - `columns`: the names of the file's time, input and output columns, e.g.
      `("time_s", "voltage_V", "displacement_um")` or `"time_s,voltage_V,displacement_um"`
      (default: `t`, `u`, `y`); they become the record's `t`, `u`, `y`. Two names (`"H,B"`)
      name the input and output of data without time.

    **Returns:** a [`Record`][]. Raises [`DataError`][] (a `ValueError`) naming the file, the row
    where it applies, and the problem: missing columns, non-numeric cells, NaN/inf, too few
    samples, time not strictly increasing, non-uniform sampling, a gap too long to resample,
    mismatched lengths, a segment whose rows are not together.
    """
    path, source = _existing(path)
    names = column_names(columns, source)
    opts = dict(min_samples=min_samples, dt_tolerance=dt_tolerance, resample=resample, max_gap=max_gap)
    if path.suffix.lower() == ".npz":
        return _load_npz(path, source, names, **opts)
    if names is None:
        cols, rows, names = _read_csv(path, source, ("t", "u", "y"), COLUMNS_HINT, quasi=True)
    else:
        cols, rows, _ = _read_csv(path, source, tuple(n for n in names if n is not None))
    return _chosen(cols, names, source, rows, **opts)


def _chosen(cols, names, source, rows, **opts):
    """The record of the columns `names` (time or None, input, output) of `cols`."""
    time = names[0]
    seg = cols.pop(SEGMENT, None) if SEGMENT not in names else None
    chosen = {k: cols.pop(n) for k, n in zip(("t", "u", "y"), names) if n is not None}
    if time is None:
        chosen["t"] = np.arange(len(chosen["u"]), dtype=np.float64)
    # A column of the file named t, u or y that was not chosen would shadow the chosen one.
    extras = {k: v for k, v in cols.items() if k not in ("t", "u", "y")}
    indexed = time is None or time in INDEX_NAMES
    return _record(chosen["t"], chosen["u"], chosen["y"], extras, source, rows, seg, indexed, **opts)


def _existing(path):
    path = Path(path)
    source = str(path)
    if not path.exists():
        _fail(source, "no such file")
    if path.is_dir():
        _fail(source, "is a folder, not a data file")
    if not path.is_file():
        # A device or pipe (/dev/zero, a FIFO) could be read forever.
        _fail(source, "is not a regular file")
    return path, source


# Files larger than this are first read straight from disk by NumPy's parser (`_stream_rows`):
# a 10^7-row file then costs its array, not its text as Python lines (1.8 GB for 354 MB).
STREAM_BYTES = 32 * 2**20


def _head_lines(path):
    """The first `_HEADER_SEARCH_LINES` lines of a text file (where the header is looked for)."""
    with open(path, encoding="utf-8-sig", newline=None) as f:
        head = []
        for line in f:
            head.append(line.rstrip("\n"))
            if len(head) >= _HEADER_SEARCH_LINES:
                break
    return head


def _stream_rows(path, h, delim, ncol, trailing):
    """The data rows below header line `h` as NumPy parses them from the file, with their line
    numbers; None when the data part has anything but plain rows (blank or `#` lines, quotes,
    a cell NumPy does not read), which the line-by-line parser then handles and names."""
    raw = path.read_bytes()
    start = 0
    for _ in range(h + 1):
        start = raw.find(b"\n", start) + 1
        if start == 0:
            return None
    body = raw[start:]
    del raw
    plain = not any(m in body for m in (b"#", b'"', b"\n\n", b"\n\r\n", b"\r\r"))
    n = body.count(b"\n") + (0 if body.endswith(b"\n") or not body else 1)
    del body
    if not plain or n == 0:
        return None
    try:
        data = np.loadtxt(
            path,
            delimiter=delim,
            skiprows=h + 1,
            ndmin=2,
            encoding="utf-8-sig",
            usecols=range(ncol) if trailing else None,
            comments=None,
        )
    except (ValueError, UnicodeDecodeError):
        return None
    if data.shape != (n, ncol):
        return None
    return data, np.arange(h + 2, h + 2 + n)


def _read_csv(path, source, required, hint="", quasi=False):
    """Columns by (lower-case) name, the file's line number of each data row, and (with `quasi`)
    the record's (time, input, output) names: a header with u and y but no t is taken too."""
    if path.stat().st_size > STREAM_BYTES:
        # Anything unusual (no header near the top, a malformed row) is left to the line-by-line
        # parser below, which names it.
        try:
            h, delim, names, chosen, trailing = _header(_head_lines(path), source, required, hint, quasi)
            got = _stream_rows(path, h, delim, len(names), trailing)
        except (DataError, UnicodeDecodeError):
            got = None
        if got is not None:
            data, rows = got
            return {n: data[:, j].copy() for j, n in enumerate(names)}, rows, chosen
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError:
        _fail(source, "is not a text (UTF-8) CSV file")
    lines = text.splitlines()
    del text
    h, delim, names, chosen, trailing = _header(lines, source, required, hint, quasi)
    data, rows = _parse_rows(lines, h + 1, delim, names, source, trailing=trailing)
    return {n: data[:, j].copy() for j, n in enumerate(names)}, rows, chosen


def _header(lines, source, required, hint, quasi):
    """The header's line index, delimiter, column names, the record's chosen names (`quasi`)
    and whether every line ends with a delimiter; refuses a missing or duplicated column."""
    found = None
    if quasi:
        found = next((c for c in _header_candidates(lines) if set(required) <= set(c[2])), None)
        found = found or next((c for c in _header_candidates(lines) if {"u", "y"} <= set(c[2])), None)
        found = found or next((c for c in _header_candidates(lines) if by_role(c[2]) is not None), None)
    h, delim, names = found or _find_header(lines, source, required, hint)
    chosen = _pick(names, None, source, "the header", h + 1, hint) if quasi else None
    dupes = sorted({n for n in names if names.count(n) > 1})
    if dupes:
        _fail(source, f"duplicated column name(s) in the header: {', '.join(dupes)}", h + 1)
    # A delimiter at the end of every line (common in instrument exports) is not a column.
    trailing = lines[h].rstrip(" \r\n").endswith(delim)
    if trailing and len(names) > 1 and names[-1] == "":
        names = names[:-1]
    return h, delim, names, chosen, trailing


def load_columns(path, required=("t",), *, min_samples: int = 2, time: str = "t") -> dict:
    """Read named columns from a CSV, with the same tolerance and messages as [`load_record`][].

    For files that are not (t, u, y) records, e.g. a desired output trajectory. The required
    columns must be finite; a required `t` must be strictly increasing (uniform steps are not
    needed).

    **Arguments:**

    - `path`: the CSV file (any of `,` `;` tab as delimiter; preamble and `#` lines skipped).
    - `required`: the column names that must be in the header (lower case).
    - `min_samples`: fewer data rows than this are rejected.
    - `time`: the name of the time column, checked for increase when it is required.

    **Returns:** a dict from lower-case column name to a float64 array (T,). Raises
    [`DataError`][] naming the file, the row and the problem.
    """
    path, source = _existing(path)
    required = tuple(base_name(r) for r in required)
    time = base_name(time)
    cols, rows, _ = _read_csv(path, source, required)
    for name in required:
        bad = ~np.isfinite(cols[name])
        if bad.any():
            k = int(np.argmax(bad))
            _fail(source, f"column `{name}` holds {cols[name][k]} (NaN or inf are not data)", rows[k])
    n = len(rows)
    if n < min_samples:
        _fail(source, f"only {n} sample{'s' * (n != 1)}; at least {min_samples} are needed")
    if time in required:
        dt = np.diff(cols[time])
        if np.any(dt <= 0):
            k = int(np.argmax(dt <= 0))
            what = "repeats" if dt[k] == 0 else "goes backwards"
            t = float(cols[time][k + 1])
            _fail(source, f"time is not strictly increasing: t = {t:.10g} {what}", rows[k + 1])
    return cols


def _load_npz(path, source, names=None, **opts):
    try:
        # Our own handle: np.load leaves its file open when the archive is corrupt.
        with open(path, "rb") as fh, np.load(fh, allow_pickle=False) as z:
            arrays = {k: np.asarray(z[k]) for k in z.files}
    except Exception as e:  # a corrupt archive can raise many kinds of error
        _fail(source, f"cannot be read as NPZ ({type(e).__name__}: {e})")
    byname = {base_name(k): k for k in arrays}
    if names is None:
        if not {"u", "y"} <= set(byname) or "t" in byname:
            missing = [k for k in ("t", "u", "y") if k not in arrays]
            if missing:
                _fail(source, f"missing array(s) {', '.join(missing)}; found {sorted(arrays)}")
        names = _pick(list(byname), None, source, "the archive")
    else:
        missing = [n for n in names if n is not None and n not in byname]
        if missing:
            _fail(source, f"missing array(s) {', '.join(missing)}; found {sorted(arrays)}")
    used = {byname[n] for n in names if n is not None}
    cols = {}
    for k, v in arrays.items():
        if v.ndim != 1:
            if k in used:
                _fail(source, f"array `{k}` must be one-dimensional, got shape {v.shape}")
            continue
        if np.issubdtype(v.dtype, np.complexfloating):
            _fail(source, f"array `{k}` is complex (dtype {v.dtype}); store real values")
        if not np.issubdtype(v.dtype, np.number):
            _fail(source, f"array `{k}` is not numeric (dtype {v.dtype})")
        cols[base_name(k)] = v.astype(np.float64)
    first = names[0] if names[0] is not None else names[1]
    n = len(cols[first])
    for k, v in cols.items():
        if len(v) != n:
            _fail(source, f"array `{k}` has {len(v)} samples but `{first}` has {n}")
    return _chosen(cols, names, source, None, **opts)


def datasets() -> list[str]:
    """The names of the measured data sets shipped with the package (see `piest_jax/data/`).

    **Returns:** the sorted names, e.g. `"piezo_aye2018_identification"`; each one is accepted by
    [`load_dataset`][] and [`dataset_path`][].
    """
    root = resources.files("piest_jax") / "data"
    return sorted(p.name[: -len(".csv")] for p in root.iterdir() if p.name.endswith(".csv"))


def dataset_path(name: str) -> Path:
    """The path of a shipped data set's CSV file.

    **Arguments:** `name`, a name from [`datasets`][] (the file name, with `.csv`, is accepted too).

    **Returns:** its `Path`. Raises `ValueError` listing the available names otherwise.
    """
    names = datasets()
    stem = name[: -len(".csv")] if name.endswith(".csv") else name
    if stem not in names:
        raise ValueError(f"no shipped data set {name!r}; available: {', '.join(names)}")
    return Path(str(resources.files("piest_jax") / "data" / f"{stem}.csv"))


def load_dataset(name: str, **kwargs) -> Record:
    """Load a shipped data set as a [`Record`][].

    **Arguments:** `name`, a name from [`datasets`][]; `kwargs` go to [`load_record`][].

    **Returns:** the record; its `source` is the file's path.
    """
    return load_record(dataset_path(name), **kwargs)
