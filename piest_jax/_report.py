"""Writing results as strict JSON and reproducible figures, for library users and experiments.

The `piest` commands write through their own transactional writer (`_cli/output.py`), which
encodes JSON with the functions here, so a report reads the same from either.
"""

import json
import math
from pathlib import Path

import numpy as np


class NonFiniteError(ValueError):
    """A result that should be a number is NaN or infinite."""


def _where(keys) -> str:
    text = ""
    for k in keys:
        text += f"[{k}]" if isinstance(k, int) else (f".{k}" if text else str(k))
    return text or "the value"


def _jsonable(x, keys=(), bad=None):
    """`x` as plain JSON types; each non-finite float becomes None and its location goes to `bad`."""
    bad = [] if bad is None else bad
    if isinstance(x, dict):
        return {str(k): _jsonable(v, (*keys, str(k)), bad) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v, (*keys, i), bad) for i, v in enumerate(x)]
    if hasattr(x, "__array__") and not isinstance(x, (str, bytes)):
        arr = np.asarray(x)
        return _jsonable(arr.item() if arr.ndim == 0 else arr.tolist(), keys, bad)
    if isinstance(x, (np.bool_, bool)):
        return bool(x)
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, (np.floating, float)):
        x = float(x)
        if math.isfinite(x):
            return x
        # JSON has no NaN or inf: the value is written as null and flagged, never silently.
        bad.append((keys, x))
        return None
    if isinstance(x, Path):
        return str(x)
    return x


def check_finite(name: str, bad, allowed) -> None:
    """Refuse non-finite values outside the keys where they mean something (`allowed`; None:
    everywhere, as for library use outside a command)."""
    if allowed is None:
        return
    refused = [(k, v) for k, v in bad if not any(str(c) in allowed for c in k)]
    if refused:
        keys, v = refused[0]
        more = f" (and {len(refused) - 1} more values)" if len(refused) > 1 else ""
        raise NonFiniteError(f"the result is not finite: {_where(keys)} = {v} in {name}{more}; nothing was written")


def json_text(obj, *, name: str = "the report", allowed=None) -> str:
    """`obj` as indented, strict JSON text (what [`write_json`][] writes).

    **Arguments:** `obj`, nested dicts/lists of numbers, strings, arrays, paths; `name`, how error
    messages call the report; `allowed`, the keys that may hold a non-finite number (None: all).

    **Returns:** the text, ending in a newline. Non-finite numbers become `null` and are listed
    under the top-level `"non_finite"` key; outside `allowed` they raise [`NonFiniteError`][].
    """
    bad: list[tuple[tuple, float]] = []
    data = _jsonable(obj, (), bad)
    check_finite(name, bad, allowed)
    if bad:
        if not isinstance(data, dict):
            raise NonFiniteError(f"{name}: non-finite values can only be flagged in a JSON object")
        data["non_finite"] = {_where(k): str(v) for k, v in bad}
    return json.dumps(data, indent=2, allow_nan=False) + "\n"


def write_json(path, obj) -> Path:
    """Write a result as indented, strict JSON, as the `piest` commands write their reports.

    Arrays and NumPy or JAX scalars become plain numbers and lists. JSON has no NaN or infinity:
    a non-finite number is written as `null` and its location and value are listed under the
    top-level key `"non_finite"` (for example `{"sweep.time_to_1pct[0]": "inf"}`).

    **Arguments:** `path`, the destination (its folder is created); `obj`, nested dicts/lists of
    numbers, strings and arrays.

    **Returns:** the path written.
    """
    path = Path(path)
    text = json_text(obj, name=path.name)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def figure_options(path, kwargs: dict) -> tuple[str, dict]:
    """The format of `path` and `savefig` options with fixed metadata, which keeps PNGs
    byte-identical between runs."""
    fmt = Path(path).suffix.lstrip(".") or "png"
    kwargs = dict(kwargs)
    kwargs.setdefault("metadata", {"Software": None} if fmt == "png" else {})
    return fmt, kwargs


def save_figure(fig, path, **kwargs) -> Path:
    """Save a matplotlib figure reproducibly (the same file from the same figure, run after run).

    **Arguments:** `fig`, a `matplotlib.figure.Figure`; `path`, the destination (its suffix picks
    the format; its folder is created); `kwargs`, passed to `Figure.savefig` (e.g. `dpi`).

    **Returns:** the path written. The figure is left open and pyplot's state untouched.
    """
    path = Path(path)
    fmt, kwargs = figure_options(path, kwargs)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, format=fmt, **kwargs)
    return path
