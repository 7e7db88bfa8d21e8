"""Fitted models as JSON files: `save_model`, `load_model`, and one entry per model structure.

A model file is a JSON object with a `"schema"` version and a `"structure"` naming the kind of
model; the other keys are that structure's parameters. `piest fit` writes its `fit.json` in this
form (with its diagnostics beside the model's keys), so `load_model("fit.json")` gives the fitted
model back. Files written before the schema key existed hold a PI model and load as one.

A new model structure registers itself once, at the bottom of this file: its name, the classes
it writes, and the functions between a model and its keys.
"""

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from .._data.record import DataError
from .._models.composite import HysteresisModel
from .._models.creep import Creep
from .._models.gpi import GeneralizedPI
from .._models.preisach import Preisach
from .._operators.pi import PIOperator
from .._report import write_json
from .fit import PIFit
from .fit_gpi import GPIFit
from .fit_preisach import PreisachFit

SCHEMA = 1


class _Structure(NamedTuple):
    types: tuple[type, ...]
    to_keys: Callable[[Any], dict]
    from_keys: Callable[[dict, str], Any]


_STRUCTURES: dict[str, _Structure] = {}


def register_structure(name: str, types, to_keys, from_keys) -> None:
    """Make `save_model` write models of `types` as `"structure": name` and `load_model` read them.

    `to_keys(model)` gives the JSON-ready parameters; `from_keys(keys, source)` builds the model
    from a file's object and raises [`DataError`][] starting with `source` when a key is wrong.
    """
    _STRUCTURES[name] = _Structure(tuple(types), to_keys, from_keys)


def model_keys(model) -> dict:
    """The JSON object [`save_model`][] writes for `model`: schema, structure, parameters.

    **Arguments:** `model`, of a registered structure (a [`PIFit`][],
    [`PIOperator`][], [`HysteresisModel`][], [`GeneralizedPI`][piest_jax.GeneralizedPI] or
    [`Preisach`][piest_jax.Preisach]; a [`GPIFit`][piest_jax.GPIFit] or
    [`PreisachFit`][piest_jax.PreisachFit] saves its model).

    **Returns:** a dict, ready for `json.dumps` once arrays become lists. Raises `TypeError`
    for a model of no registered structure.
    """
    if isinstance(model, PIFit):
        model = model.model()
    if isinstance(model, GPIFit | PreisachFit):
        model = model.model
    # A composite model names its own structure (PI alone or PI + creep); others by their class.
    named = getattr(model, "structure", None)
    if isinstance(named, str) and named in _STRUCTURES and isinstance(model, _STRUCTURES[named].types):
        return {"schema": SCHEMA, "structure": named, **_STRUCTURES[named].to_keys(model)}
    for name, s in _STRUCTURES.items():
        if isinstance(model, s.types):
            return {"schema": SCHEMA, "structure": name, **s.to_keys(model)}
    kinds = ", ".join(t.__name__ for s in _STRUCTURES.values() for t in s.types)
    raise TypeError(f"cannot save a {type(model).__name__}; saved models are {kinds}")


def model_from_keys(keys, source: str = "<model>"):
    """The model a file's JSON object describes (the inverse of [`model_keys`][]).

    **Arguments:** `keys`, the decoded JSON object; `source`, how error messages name it.

    **Returns:** the model (a [`HysteresisModel`][] for `"structure": "pi"` and `"pi+creep"`). Raises [`DataError`][]
    naming `source` and the problem: not an object, a schema newer than this version reads, an
    unknown structure, or a parameter that is missing, not a number, not finite or of the
    wrong length.
    """
    if not isinstance(keys, dict):
        raise DataError(f"{source}: expected a JSON object as written by `piest fit`")
    schema = keys.get("schema", 0)
    if isinstance(schema, bool) or not isinstance(schema, int) or schema < 0:
        raise DataError(f"{source}: `schema` must be a non-negative integer, got {schema!r}")
    if schema > SCHEMA:
        raise DataError(
            f"{source}: model file schema {schema} is newer than this piest_jax reads ({SCHEMA}); upgrade piest_jax"
        )
    name = keys.get("structure", "pi")
    if "structure" not in keys and keys.get("creep") is not None:
        # Read as a plain PI, the creep would be dropped without a word.
        raise DataError(f'{source}: it has a `creep` but no `"structure": "pi+creep"` to say it is used')
    if name not in _STRUCTURES:
        raise DataError(f"{source}: unknown model structure {name!r}; this piest_jax reads {', '.join(_STRUCTURES)}")
    return _STRUCTURES[name].from_keys(keys, source)


def save_model(path, model) -> Path:
    """Write a model as a JSON model file that [`load_model`][] reads back.

    **Arguments:** `path`, the destination (its folder is created); `model`, a [`PIFit`][]
    (its model part), a [`PIOperator`][] (offset 0), a [`HysteresisModel`][], a
    [`GeneralizedPI`][piest_jax.GeneralizedPI] or a [`Preisach`][piest_jax.Preisach] (or the
    fit holding one).

    **Returns:** the path written. Raises `ValueError` when a parameter is not finite.
    """
    keys = model_keys(model)
    bad = [k for k, v in keys.items() if isinstance(v, np.ndarray) and not np.all(np.isfinite(v))]
    if bad:
        raise ValueError(f"cannot save a model with non-finite {', '.join(bad)}")
    return write_json(path, keys)


def load_model(path):
    """Read a model from a JSON model file: one written by [`save_model`][] or `piest fit`'s
    `fit.json` (older `fit.json` files without a schema key included).

    **Arguments:** `path`, the file.

    **Returns:** the model, callable on an input: `load_model("fit.json")(u)` is the fitted
    model's output (a [`HysteresisModel`][] for a PI or PI + creep fit). Model files hold
    float64 numbers; the model's arrays take JAX's precision (float64 with `jax_enable_x64`, as
    the `piest` commands run). Raises [`DataError`][] (a `ValueError`) naming the file and the
    problem.
    """
    return model_from_keys(read_json(path), str(Path(path)))


# A model of a million plays is about 60 MB of JSON; anything larger is not a model file.
MAX_JSON_BYTES = 256 * 2**20


def read_json(path, *, max_bytes: int | None = None):
    """A JSON file decoded with limits: its size, its nesting (a deep file is refused, not a
    RecursionError), and integers too long for a float (read as inf, then refused as not finite).

    **Arguments:** `path`; `max_bytes`, the largest file read (default `MAX_JSON_BYTES`, 256 MB).

    **Returns:** the decoded value. Raises [`DataError`][] naming the file and the problem.
    """
    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: no such file" if not path.exists() else f"{path}: not a file")
    size = path.stat().st_size
    max_bytes = MAX_JSON_BYTES if max_bytes is None else max_bytes
    if size > max_bytes:
        raise DataError(
            f"{path}: {size / 2**20:.0f} MB is more than a model file holds ({max_bytes / 2**20:.0f} MB at most)"
        )
    try:
        return json.loads(path.read_text(), parse_int=_integer)
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise DataError(f"{path}: not a JSON file ({e})") from None
    except RecursionError:
        raise DataError(f"{path}: not a model file (nested too deeply)") from None


def _integer(text: str):
    # Integers beyond float64's range become inf (refused later as not finite), not an
    # OverflowError when converted; 20 digits keep every int64.
    return int(text) if len(text.lstrip("-")) <= 20 else float(text)


def _no_booleans(d: dict, keys, source: str) -> None:
    """JSON's `true` and `false` are not numbers, although Python counts them as 0 and 1."""

    def has_bool(v):
        return isinstance(v, bool) or (isinstance(v, list) and any(has_bool(x) for x in v))

    for k in keys:
        if has_bool(d.get(k)):
            raise DataError(f"{source}: `{k}` holds true or false; it must be numbers")


# --- the PI model -----------------------------------------------------------------------------


def _pi_keys(model) -> dict:
    # `model_keys` has taken a fit's model already.
    if isinstance(model, PIOperator):
        model = HysteresisModel(model)
    return {
        "thresholds": np.asarray(model.pi.thresholds, np.float64),
        "weights": np.asarray(model.pi.weights, np.float64),
        "offset": np.asarray(model.offset, np.float64),
        "initial_states": np.asarray(model.pi.initial_states, np.float64),
    }


def _pi_from_keys(d: dict, source: str) -> HysteresisModel:
    # PI files with a schema are written whole by `save_model`; older ones may lack the last two.
    whole = "schema" in d and d.get("structure", "pi") in ("pi", "pi+creep")
    required = ("thresholds", "weights") + (("offset", "initial_states") if whole else ())
    missing = [k for k in required if k not in d]
    if missing:
        raise DataError(f"{source}: missing {', '.join(missing)} (is it a `piest fit` fit.json?)")
    _no_booleans(d, ("thresholds", "weights", "offset", "initial_states"), source)
    try:
        r = np.asarray(d["thresholds"], dtype=float)
        w = np.asarray(d["weights"], dtype=float)
        c = float(d.get("offset", 0.0))
        x0 = np.asarray(d.get("initial_states", 0.0), dtype=float)
    except (TypeError, ValueError) as e:
        raise DataError(f"{source}: thresholds, weights, offset must be numbers ({e})") from None
    if r.ndim != 1 or r.shape != w.shape:
        raise DataError(f"{source}: thresholds {r.shape} and weights {w.shape} must be equal vectors")
    if r.size == 0:
        raise DataError(f"{source}: the model has no plays (empty thresholds and weights)")
    if x0.ndim > 1 or x0.size not in (1, r.size):
        raise DataError(f"{source}: initial_states has {x0.size} entries for {r.size} plays")
    if not all(np.all(np.isfinite(a)) for a in (r, w, c, x0)):
        raise DataError(f"{source}: thresholds, weights, offset and initial_states must be finite")
    try:
        return HysteresisModel(PIOperator(r, w, x0), None, c)
    except ValueError as e:
        raise DataError(f"{source}: {e}") from None


register_structure("pi", (PIFit, PIOperator, HysteresisModel), _pi_keys, _pi_from_keys)


# --- PI + creep (a bank of first-order lags of the input) ------------------------------------


def _creep_keys(model: HysteresisModel) -> dict:
    c = model.creep
    assert c is not None  # the structure "pi+creep" names models with a creep only
    creep = {
        "time_constants": np.asarray(c.time_constants, np.float64),
        "weights": np.asarray(c.weights, np.float64),
        "dt": float(c.dt),
        # At rest: each lag starts at the first input of whatever record the model runs on.
        "starts_at_rest": c.initial_states is None,
    }
    if c.initial_states is not None:
        creep["initial_states"] = np.asarray(c.initial_states, np.float64)
    return {**_pi_keys(model), "dt": float(model.dt), "creep": creep}


def _creep_from_keys(d: dict, source: str) -> HysteresisModel:
    pi = _pi_from_keys(d, source)
    cr = d.get("creep")
    if not isinstance(cr, dict) or not {"time_constants", "weights", "dt"} <= set(cr):
        raise DataError(f"{source}: `creep` must hold time_constants, weights and dt")
    _no_booleans(cr, ("time_constants", "weights", "dt", "initial_states"), source + ": creep")
    try:
        z0 = cr.get("initial_states")
        creep = Creep(
            np.asarray(cr["time_constants"], float),
            np.asarray(cr["weights"], float),
            float(cr["dt"]),
            None if z0 is None else np.asarray(z0, float),
        )
        return HysteresisModel(pi.pi, creep, pi.offset, float(cr["dt"]))
    except (TypeError, ValueError) as e:
        raise DataError(f"{source}: unusable creep ({' '.join(str(e).split())})") from None


register_structure("pi+creep", (HysteresisModel,), _creep_keys, _creep_from_keys)


# --- the generalized PI (a PI operator, then a saturating output function) --------------------


def _gpi_keys(model: GeneralizedPI) -> dict:
    return {
        **_pi_keys(model.pi),
        "offset": np.asarray(model.offset, np.float64),
        # g(v) = offset + Σ_k amplitudes_k tanh((v - centres_k)/scales_k), v the PI's output.
        "output_function": {
            "form": "tanh",
            "amplitudes": np.asarray(model.amplitudes, np.float64),
            "centres": np.asarray(model.centres, np.float64),
            "scales": np.asarray(model.scales, np.float64),
        },
    }


def _gpi_from_keys(d: dict, source: str) -> GeneralizedPI:
    pi = _pi_from_keys(d, source)
    g = d.get("output_function")
    if not isinstance(g, dict) or not {"amplitudes", "centres", "scales"} <= set(g):
        raise DataError(f"{source}: `output_function` must hold amplitudes, centres and scales")
    if g.get("form", "tanh") != "tanh":
        raise DataError(f"{source}: unknown output function form {g.get('form')!r}; this piest_jax reads 'tanh'")
    _no_booleans(g, ("amplitudes", "centres", "scales"), source + ": output_function")
    try:
        a, c, s = (np.asarray(g[k], dtype=float) for k in ("amplitudes", "centres", "scales"))
        if not all(np.all(np.isfinite(v)) for v in (a, c, s)):
            raise ValueError("amplitudes, centres and scales must be finite")
        return GeneralizedPI(pi.pi, a, c, s, pi.offset)
    except (TypeError, ValueError) as e:
        raise DataError(f"{source}: unusable output_function ({' '.join(str(e).split())})") from None


register_structure("gpi", (GeneralizedPI,), _gpi_keys, _gpi_from_keys)


# --- the discrete Preisach model (blurred relays on a half-width × centre grid) ---------------


def _preisach_keys(model: Preisach) -> dict:
    keys = {
        "half_widths": np.asarray(model.half_widths, np.float64),
        "centres": np.asarray(model.centres, np.float64),
        "blur": np.asarray(model.blur, np.float64),
        "density": np.asarray(model.density, np.float64),
        "offset": np.asarray(model.offset, np.float64),
        # At rest: every play starts at the first input of whatever record the model runs on.
        "starts_at_rest": model.initial_states is None,
    }
    if model.initial_states is not None:
        keys["initial_states"] = np.asarray(model.initial_states, np.float64)
    return keys


def _preisach_from_keys(d: dict, source: str) -> Preisach:
    names = ("half_widths", "centres", "blur", "density", "offset", "initial_states")
    missing = [k for k in names[:4] if k not in d]
    if missing:
        raise DataError(
            f"{source}: missing {', '.join(missing)} (a Preisach model file holds "
            "half_widths, centres, blur and density)"
        )
    _no_booleans(d, names, source)
    try:
        x0 = d.get("initial_states")
        values = [np.asarray(d[k], dtype=float) for k in names[:4]]
        offset = float(d.get("offset", 0.0))
        if not all(np.all(np.isfinite(v)) for v in values) or not np.isfinite(offset):
            raise ValueError("half_widths, centres, blur, density and offset must be finite")
        r, c, blur, mu = values
        return Preisach(r, c, mu, offset, None if x0 is None else np.asarray(x0, float), blur)
    except (TypeError, ValueError) as e:
        raise DataError(f"{source}: unusable Preisach model ({' '.join(str(e).split())})") from None


register_structure("preisach", (Preisach,), _preisach_keys, _preisach_from_keys)
