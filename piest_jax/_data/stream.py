"""A long CSV record read in chunks, never whole: for the commands that stream (`piest estimate`).

`open_record_stream` reads the header as [`load_record`][piest_jax.load_record] does (names without
case or units, `columns=` to choose them, data without time), then checks every row in one pass
of fixed-size chunks: finite numbers, time strictly increasing, steps uniform. It gives up (returns
None) on anything that `load_record` handles or names better when it holds the file whole: lines
that are not plain rows of numbers, a `segment` column, too few samples, or steps whose largest
exceeds the smallest by more than the tolerance (where `load_record`'s test against the median
step decides). The stream's `dt` is the mean step; on a record that passes, it differs from
`load_record`'s median step by less than the tolerance (in practice by rounding).
"""

import dataclasses
import itertools
from pathlib import Path

import numpy as np

from .columns import INDEX_NAMES, SEGMENT, column_names
from .record import COLUMNS_HINT, MIN_SAMPLES, DataError, _existing, _head_lines, _header

#: Rows parsed at once.
CHUNK_ROWS = 1 << 16


@dataclasses.dataclass(frozen=True)
class RecordStream:
    """A checked CSV record, read again chunk by chunk whenever it is iterated.

    **Fields:** `path`; `n_samples`; `t0`, `dt` (the first time and the mean step; a time that
    counts samples gives 0 and 1); `time_is_index`; `u_min`, `u_max`, `u_first` (the input's
    range and first sample); `y_peak` (max |y|).
    """

    path: Path
    n_samples: int
    t0: float
    dt: float
    time_is_index: bool
    u_min: float
    u_max: float
    u_first: float
    y_peak: float
    _skip: int = dataclasses.field(repr=False)
    _delim: str = dataclasses.field(repr=False)
    _cols: tuple = dataclasses.field(repr=False)

    def _rows(self, size: int):
        with open(self.path, encoding="utf-8-sig", newline=None) as f:
            for _ in range(self._skip):
                next(f, None)
            while lines := list(itertools.islice(f, size)):
                data = np.loadtxt(
                    lines, delimiter=self._delim, ndmin=2, comments=None, dtype=np.float64, usecols=self._cols
                )
                yield data

    def chunks(self, size: int = CHUNK_ROWS):
        """Consecutive `(u, y)` arrays of `size` samples (the last may be shorter)."""
        for data in self._rows(size):  # (t,) u, y: the last two columns read
            yield data[:, -2].copy(), data[:, -1].copy()


def _plain_columns(path, source, names):
    """Header line, delimiter and the (t or None, u, y) column indices; None to read it whole."""
    lines = _head_lines(path)
    if names is None:
        h, delim, header, chosen, _ = _header(lines, source, ("t", "u", "y"), COLUMNS_HINT, quasi=True)
    else:
        h, delim, header, _, _ = _header(lines, source, tuple(n for n in names if n is not None), "", False)
        chosen = names
    if SEGMENT in header and SEGMENT not in chosen:
        return None
    return h, delim, header, chosen


def open_record_stream(path, *, columns=None, dt_tolerance: float = 1e-3) -> RecordStream | None:
    """Check a CSV record in one pass of chunks and return it as a [`RecordStream`][], or None
    when [`load_record`][piest_jax.load_record] should read it whole (see the module docstring).

    **Arguments:** `path`; `columns` as for `load_record`; `dt_tolerance` the largest relative
    spread of the time steps.

    **Returns:** the stream, or None. A missing column raises `DataError` as `load_record` does.
    """
    path, source = _existing(path)
    names = column_names(columns, source)
    if path.suffix.lower() != ".csv":
        return None
    try:
        found = _plain_columns(path, source, names)
    except UnicodeDecodeError:
        return None
    if found is None:
        return None
    h, delim, header, chosen = found
    time = chosen[0]
    cols = tuple(header.index(n) for n in chosen if n is not None)
    indexed = time is None or time in INDEX_NAMES
    probe = RecordStream(path, 0, 0.0, 1.0, indexed, 0.0, 0.0, 0.0, 0.0, h + 1, delim, cols)
    n, t0, t_prev = 0, None, None
    lo_step, hi_step = np.inf, 0.0
    u_min, u_max, y_peak, u_first = np.inf, -np.inf, 0.0, None
    try:
        for data in probe._rows(CHUNK_ROWS):
            if time is None:
                data = np.column_stack([n + np.arange(len(data), dtype=np.float64), data])
            if data.shape[1] != 3 or not np.all(np.isfinite(data)):
                return None
            t, u, y = data.T
            steps = np.diff(t if t_prev is None else np.concatenate([[t_prev], t]))
            if steps.size:
                if steps.min() <= 0:
                    return None
                lo_step, hi_step = min(lo_step, steps.min()), max(hi_step, steps.max())
            if t0 is None:
                t0, u_first = float(t[0]), float(u[0])
            t_prev = float(t[-1])
            n += len(t)
            u_min, u_max = min(u_min, u.min()), max(u_max, u.max())
            y_peak = max(y_peak, float(np.abs(y).max()))
    except (ValueError, UnicodeDecodeError, DataError):
        return None
    # Every step within the tolerance of every other: then load_record's test against the median
    # passes too; anything else it decides itself.
    if n < MIN_SAMPLES or hi_step > lo_step * (1 + dt_tolerance):
        return None
    # At least one chunk was read, so the first and last samples are set.
    assert t0 is not None and t_prev is not None and u_first is not None
    # Without a time column the rows were numbered while reading: t0 = 0, dt = 1.
    return dataclasses.replace(
        probe,
        n_samples=n,
        t0=t0,
        dt=(t_prev - t0) / (n - 1),
        u_min=float(u_min),
        u_max=float(u_max),
        u_first=u_first,
        y_peak=y_peak,
    )
