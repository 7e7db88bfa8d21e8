"""Loading measured (t, u, y) records from CSV or NPZ, with errors that name the file and row."""

import dataclasses
import io
from importlib import resources
from pathlib import Path

import numpy as np

MIN_SAMPLES = 8
_DELIMITERS = (",", ";", "\t")
_HEADER_SEARCH_LINES = 200


class DataError(ValueError):
    """A data file that cannot be used, with a message naming the file, row and problem."""


@dataclasses.dataclass(frozen=True)
class Record:
    """A uniformly sampled measurement: time `t`, input `u`, output `y` (all float64, (T,)).

    **Fields:**

    - `t`, `u`, `y`: the three required columns.
    - `extras`: any further columns by name (e.g. `desired`), each (T,).
    - `source`: where the record came from (a path or a description).
    """

    t: np.ndarray
    u: np.ndarray
    y: np.ndarray
    extras: dict = dataclasses.field(default_factory=dict)
    source: str = "<memory>"

    def __post_init__(self):
        n = len(self.t)
        for name, col in [("u", self.u), ("y", self.y), *self.extras.items()]:
            if np.shape(col) != (n,):
                raise DataError(
                    f"{self.source}: column `{name}` has shape {np.shape(col)}, expected ({n},)"
                )

    @property
    def n_samples(self) -> int:
        """The number of samples T."""
        return len(self.t)

    @property
    def dt(self) -> float:
        """The sampling interval (the median step of `t`)."""
        return float(np.median(np.diff(self.t)))

    def slice(self, start: int | None = None, stop: int | None = None) -> "Record":
        """The samples `start:stop` as a new record (time stamps kept)."""
        sl = slice(start, stop)
        extras = {k: v[sl] for k, v in self.extras.items()}
        return Record(self.t[sl], self.u[sl], self.y[sl], extras, self.source)


def _fail(source, msg, row=None):
    where = f"{source}, row {row}" if row is not None else str(source)
    raise DataError(f"{where}: {msg}")


def _find_header(lines, source):
    for i, line in enumerate(lines[:_HEADER_SEARCH_LINES]):
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        delim = max(_DELIMITERS, key=stripped.count)
        names = [c.strip().strip('"').strip("'").lower() for c in stripped.split(delim)]
        if {"t", "u", "y"} <= set(names):
            return i, delim, names
    first = next((ln.strip() for ln in lines if ln.strip()), None)
    if first is None:
        _fail(source, "the file is empty")
    _fail(
        source,
        "no header row naming the columns t, u and y was found "
        f"(first line: {first[:80]!r}); a header such as `t,u,y` is required",
    )


def _parse_rows(lines, start, delim, ncol, source):
    body = [(i, ln) for i, ln in enumerate(lines[start:], start=start) if ln.strip()]
    body = [(i, ln) for i, ln in body if not ln.lstrip().startswith("#")]
    if not body:
        _fail(source, "the header is there but no data rows follow")
    try:
        data = np.loadtxt(io.StringIO("\n".join(ln for _, ln in body)), delimiter=delim, ndmin=2)
        if data.shape[1] == ncol:
            return data, [i + 1 for i, _ in body]
    except ValueError:
        pass
    # Slow path only to say exactly which row is wrong.
    rows = []
    for i, ln in body:
        cells = [c.strip() for c in ln.split(delim)]
        if len(cells) != ncol:
            _fail(source, f"expected {ncol} cells as in the header, found {len(cells)}", i + 1)
        vals = []
        for j, c in enumerate(cells):
            try:
                vals.append(float(c))
            except ValueError:
                _fail(source, f"cell {j + 1} is not a number: {c[:40]!r}", i + 1)
        rows.append(vals)
    return np.asarray(rows, dtype=np.float64), [i + 1 for i, _ in body]


def _validate(t, u, y, extras, source, rows, *, min_samples, dt_tolerance, resample):
    for name, col in [("t", t), ("u", u), ("y", y), *extras.items()]:
        bad = ~np.isfinite(col)
        if bad.any():
            k = int(np.argmax(bad))
            row = rows[k] if rows is not None else None
            _fail(source, f"column `{name}` holds {col[k]} (NaN or inf are not data)", row)
    if len(t) < min_samples:
        _fail(source, f"only {len(t)} samples; at least {min_samples} are needed")
    dt = np.diff(t)
    if np.any(dt <= 0):
        k = int(np.argmax(dt <= 0))
        row = rows[k + 1] if rows is not None else None
        what = "repeats" if dt[k] == 0 else "goes backwards"
        _fail(source, f"time is not strictly increasing: t = {t[k + 1]!r} {what}", row)
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
) -> Record:
    """Read a measured record from a CSV (header naming `t,u,y`) or an NPZ (arrays `t`, `u`, `y`).

    Lines before the header (instrument preamble) and lines starting with `#` are skipped; extra
    columns are kept in `Record.extras`.

    **Arguments:**

    - `path`: the `.csv` or `.npz` file.
    - `min_samples`: fewer samples than this are rejected.
    - `dt_tolerance`: largest relative deviation of a time step from the median step.
    - `resample`: interpolate linearly onto a uniform grid instead of rejecting non-uniform time.

    **Returns:** a [`Record`][]. Raises [`DataError`][] (a `ValueError`) naming the file, the row
    where it applies, and the problem: missing columns, non-numeric cells, NaN/inf, too few
    samples, time not strictly increasing, non-uniform sampling, mismatched lengths.
    """
    path = Path(path)
    source = str(path)
    if not path.exists():
        _fail(source, "no such file")
    if path.is_dir():
        _fail(source, "is a folder, not a data file")
    opts = dict(min_samples=min_samples, dt_tolerance=dt_tolerance, resample=resample)
    if path.suffix.lower() == ".npz":
        return _load_npz(path, source, **opts)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError:
        _fail(source, "is not a text (UTF-8) CSV file")
    lines = text.splitlines()
    h, delim, names = _find_header(lines, source)
    dupes = sorted({n for n in names if names.count(n) > 1})
    if dupes:
        _fail(source, f"duplicated column name(s) in the header: {', '.join(dupes)}", h + 1)
    data, rows = _parse_rows(lines, h + 1, delim, len(names), source)
    cols = {n: data[:, j].copy() for j, n in enumerate(names)}
    t, u, y = cols.pop("t"), cols.pop("u"), cols.pop("y")
    t, u, y, extras = _validate(t, u, y, cols, source, rows, **opts)
    return Record(t, u, y, extras, source)


def _load_npz(path, source, **opts):
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: np.asarray(z[k]) for k in z.files}
    except Exception as e:  # a corrupt archive can raise many kinds of error
        _fail(source, f"cannot be read as NPZ ({type(e).__name__}: {e})")
    missing = [k for k in ("t", "u", "y") if k not in arrays]
    if missing:
        _fail(source, f"missing array(s) {', '.join(missing)}; found {sorted(arrays)}")
    cols = {}
    for k, v in arrays.items():
        if v.ndim != 1:
            if k in ("t", "u", "y"):
                _fail(source, f"array `{k}` must be one-dimensional, got shape {v.shape}")
            continue
        if not np.issubdtype(v.dtype, np.number):
            _fail(source, f"array `{k}` is not numeric (dtype {v.dtype})")
        cols[k] = v.astype(np.float64)
    n = len(cols["t"])
    for k, v in cols.items():
        if len(v) != n:
            _fail(source, f"array `{k}` has {len(v)} samples but `t` has {n}")
    t, u, y = cols.pop("t"), cols.pop("u"), cols.pop("y")
    t, u, y, extras = _validate(t, u, y, cols, source, None, **opts)
    return Record(t, u, y, extras, source)


def builtin_datasets() -> list[str]:
    """The names of the measured data sets shipped with the package (see `piest_jax/data/`)."""
    root = resources.files("piest_jax") / "data"
    return sorted(p.name for p in root.iterdir() if p.name.endswith(".csv"))


def builtin_path(name: str) -> Path:
    """The path of a shipped data set, e.g. `"piezo_aye2018_identification.csv"`.

    **Arguments:** `name`, a file name from [`builtin_datasets`][].

    **Returns:** its `Path`. Raises `ValueError` listing the available names otherwise.
    """
    names = builtin_datasets()
    if name not in names:
        raise ValueError(f"no shipped data set {name!r}; available: {', '.join(names)}")
    return Path(str(resources.files("piest_jax") / "data" / name))
