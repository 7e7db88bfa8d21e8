"""Writing results so that an interrupted run never leaves a half-written file.

Every file is written to a temporary name in the same folder and renamed into place, which is
atomic on POSIX file systems.
"""

import json
import math
import os
import tempfile
from pathlib import Path

import numpy as np


def _jsonable(x):
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if hasattr(x, "__array__") and not isinstance(x, (str, bytes)):
        arr = np.asarray(x)
        return _jsonable(arr.item() if arr.ndim == 0 else arr.tolist())
    if isinstance(x, (np.bool_, bool)):
        return bool(x)
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, (np.floating, float)):
        x = float(x)
        # JSON has no NaN or inf; null says "not available" without breaking strict parsers.
        return x if math.isfinite(x) else None
    if isinstance(x, Path):
        return str(x)
    return x


def _atomic_write(path: Path, write) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def write_json(path, obj) -> Path:
    """Write `obj` as indented JSON (arrays become lists, NaN/inf become null), atomically.

    **Arguments:** `path`, the destination; `obj`, nested dicts/lists of numbers, strings, arrays.

    **Returns:** the path written.
    """
    text = json.dumps(_jsonable(obj), indent=2, allow_nan=False) + "\n"
    return _atomic_write(Path(path), lambda f: f.write(text.encode()))


def write_text(path, text: str) -> Path:
    """Write a text file atomically. **Returns:** the path written."""
    return _atomic_write(Path(path), lambda f: f.write(text.encode()))


def write_csv(path, columns: dict) -> Path:
    """Write equal-length columns as a CSV with a header row, atomically.

    **Arguments:** `path`; `columns`, a mapping from column name to a 1-D array.

    **Returns:** the path written.
    """
    names = list(columns)
    data = np.column_stack([np.asarray(columns[k], dtype=np.float64) for k in names])

    def write(f):
        f.write((",".join(names) + "\n").encode())
        np.savetxt(f, data, delimiter=",", fmt="%.17g")

    return _atomic_write(Path(path), write)


def save_figure(fig, path, **kwargs) -> Path:
    """Save a matplotlib figure atomically and close it. **Returns:** the path written."""
    import matplotlib.pyplot as plt

    path = Path(path)
    fmt = path.suffix.lstrip(".") or "png"
    # Fixed metadata keeps PNGs byte-identical between runs.
    kwargs.setdefault("metadata", {"Software": None} if fmt == "png" else {})
    try:
        return _atomic_write(path, lambda f: fig.savefig(f, format=fmt, **kwargs))
    finally:
        plt.close(fig)


def check_outputs(out_dir, names, force: bool) -> Path:
    """Refuse to overwrite existing results unless `force` is set.

    **Arguments:** `out_dir`, the output folder; `names`, the files a command will write;
    `force`, overwrite them if present.

    **Returns:** the output folder as a `Path` (created if missing). Raises `FileExistsError`
    naming the first existing file otherwise.
    """
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise NotADirectoryError(f"--out {out} exists and is not a folder")
    if not force:
        for name in names:
            if (out / name).exists():
                raise FileExistsError(
                    f"{out / name} already exists; pass --force to overwrite it"
                )
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise OSError(f"--out {out}: cannot create the folder ({e.strerror or e})") from None
    return out
