"""`identify` for the models that saturate: the generalized PI (`model="gpi"`) and the discrete
Preisach model (`model="preisach"`).

They take their own options (`terms`; `grid`, `smoothness`), are fitted once (no size search:
a generalized PI needs its play count; a Preisach grid is sized by `grid` and smoothed by
held-out blocks), and are judged on a validation record by their raw prediction: the plays, or
the relays, start as the identification stated (the validation record's first input when the
states were neither given nor fitted). Options the model would ignore are refused.
"""

import numpy as np

from .._data.record import Record
from . import covariance as _cov
from .compare import Comparison, fit_percent
from .fit_gpi import GPIFit, fit_gpi
from .fit_preisach import PreisachFit, fit_preisach

SATURATING = ("gpi", "preisach")
TERMS = 2  # fit_gpi's default: one term fixes the knee's shape, a second frees it
GRID = (16, 16)  # half-widths x centres: the input range resolved in sixteenths, as a 16-play PI

# The PI path's options with their defaults; a value other than the default is refused by a
# model that does not use it (each message names the option as `name`).
_PI_ONLY = {"lags": None, "time_constants": None, "candidates": None, "criterion": None}
_IGNORED: dict[str, dict[str, object]] = {
    "gpi": {**_PI_ONLY, "positive_weights": True, "grid": None, "smoothness": None},
    "preisach": {
        **_PI_ONLY,
        "plays": "auto",
        "solver": "lm",
        "starts": 4,
        "fit_initial_states": False,
        "max_threshold": None,
        "max_steps": 100,
        "terms": None,
    },
}


def check_saturating(options: dict) -> None:
    """Refuse, for `options["model"]`, the options it would ignore or cannot take.

    **Arguments:** `options`, [`identify`][piest_jax.identify]'s keyword arguments by name.

    Raises `ValueError` naming the option; nothing for the PI models but their refusal of
    `terms`, `grid` and `smoothness`.
    """
    model = options.get("model", "auto")
    if model not in SATURATING:
        for name, owner in (("terms", "gpi"), ("grid", "preisach"), ("smoothness", "preisach")):
            if options.get(name) is not None:
                raise ValueError(f"`{name}` is used only by `model` {owner}, not `model` {model}")
        return
    for name, default in _IGNORED[model].items():
        if name == "positive_weights" and options.get(name) is None:
            continue  # decided by the record's loop, for the models that can take signed weights
        if name in options and not _same(options[name], default):
            what = "signed weights (`positive_weights` False)" if name == "positive_weights" else f"`{name}`"
            raise ValueError(f"{what} does not apply to `model` {model}; leave it out")
    if model == "gpi" and options.get("plays", "auto") == "auto":
        raise ValueError("`model` gpi needs `plays` N: its number of plays is not chosen automatically")
    terms, grid, smoothness = options.get("terms"), options.get("grid"), options.get("smoothness")
    if terms is not None and not _count(terms):
        raise ValueError(f"`terms` must be a positive whole number, got {terms!r}")
    if grid is not None and not (isinstance(grid, tuple | list) and len(grid) == 2 and all(_count(g) for g in grid)):
        raise ValueError(f"`grid` must be two positive whole numbers (half-widths, centres), got {grid!r}")
    if smoothness is not None and not (np.isfinite(smoothness) and smoothness >= 0):
        raise ValueError(f"`smoothness` must be finite and >= 0, got {smoothness:g}")


def _same(value, default) -> bool:
    return value is None if default is None else bool(value == default)


def _count(value) -> bool:
    return isinstance(value, int | np.integer) and not isinstance(value, bool) and bool(value >= 1)


def fit_saturating(
    record: Record,
    mask,
    *,
    model,
    plays,
    terms,
    grid,
    smoothness,
    solver,
    key,
    starts,
    positive_weights,
    initial_states,
    fit_initial_states,
    max_threshold,
    max_steps,
) -> GPIFit | PreisachFit:
    """The model fitted on `record`'s samples where `mask` is 1 (all when None)."""
    if model == "gpi":
        return fit_gpi(
            record.u,
            record.y,
            plays,
            n_terms=TERMS if terms is None else terms,
            mask=mask,
            solver=solver,
            n_starts=starts,
            key=key,
            fit_initial_states=fit_initial_states,
            initial_states=initial_states,
            max_threshold=max_threshold,
            max_steps=max_steps,
        )
    K, M = GRID if grid is None else grid
    return fit_preisach(
        record.u,
        record.y,
        n_widths=K,
        n_centres=M,
        smoothness=smoothness,
        mask=mask,
        initial_states=initial_states,
        monotone=positive_weights,
    )


def validation_comparison(
    fit: GPIFit | PreisachFit, val: Record, initial_states, fit_initial_states
) -> tuple[Comparison, str]:
    """The raw prediction of `val` and the states it starts from, in words.

    A generalized PI's plays start at the validation record's first input unless states were
    given or fitted; a Preisach model's relays start as stated, or (none stated) as the
    record's first input leaves them.
    """
    model = fit.model
    convention = (
        "fitted (the identification record's)"
        if fit_initial_states
        else f"given ({initial_states:g})"
        if initial_states is not None
        else "first input"
    )
    if isinstance(fit, GPIFit) and not fit_initial_states:
        model = model.with_initial_states(val.u[0] if initial_states is None else initial_states)
    pred = np.asarray(model(val.u))
    rmse = float(np.sqrt(np.mean((pred - val.y) ** 2)))
    return Comparison(pred, rmse, fit_percent(val.y, pred), model), convention


def report_keys(fit: GPIFit | PreisachFit, positive_weights: bool) -> dict:
    """fit.json's keys that describe how a saturating model was fitted."""
    if isinstance(fit, GPIFit):
        m = fit.model
        return {
            "model": {"structure": "gpi", "n_plays": m.n_plays, "n_terms": m.n_terms},
            "n_plays": m.n_plays,
            "rmse": float(fit.rmse),
            **_cov.report_keys(fit),
        }
    K, M = fit.model.half_widths.shape[0], fit.model.centres.shape[0]
    return {
        "model": {"structure": "preisach", "grid": [K, M], "monotone": positive_weights},
        "grid": [K, M],
        "smoothness": fit.smoothness,
        "smoothness_candidates": list(fit.candidates),
        "held_out_rmse": list(fit.held_out_rmse),
        "n_blocks": fit.n_blocks,
        "rmse": float(fit.rmse),
        **_cov.report_keys(fit),
    }
