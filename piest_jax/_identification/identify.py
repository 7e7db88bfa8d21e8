"""Identifying a model from a measured record, as `piest fit` does: choosing its structure and
size, fitting it, and judging it on a second record.

[`identify`][piest_jax.identify] is the one call behind the command: the options are `piest
fit`'s, the result an [`Identification`][] whose `to_json()` is fit.json. It runs in three steps:

1. `check_options`: the options on their own (combinations that would be ignored are refused);
2. `plan`: the options against the record (the fitted samples, the candidates the record can
   carry), giving the largest model tried, whose size the command checks against memory;
3. the choice and the fit, then the validation, which never takes part in choosing or fitting.

A new model structure is one more name in `MODELS` and one more branch in `_choose_and_fit`; the
models that saturate (generalized PI, Preisach) take theirs from `identify_saturating.py`.
"""

import dataclasses

import numpy as np

from .._data.record import Record
from .._models.composite import HysteresisModel
from .._models.gpi import GeneralizedPI
from .._models.preisach import Preisach
from . import covariance as _cov
from .band import PredictionBand, prediction_band
from .compare import Comparison, compare, extrapolation, max_rate
from .fit import PIFit, fit_pi
from .fit_gpi import GPIFit
from .fit_preisach import PreisachFit
from .gpi_candidate import gpi_candidate
from .holdout import HOLDOUT, holdout_mask
from .identify_saturating import (
    SATURATING,
    check_saturating,
    fit_saturating,
    report_keys,
    validation_comparison,
)
from .loop import LoopDirection, loop_direction
from .model_file import model_keys
from .model_size import CRITERIA, ModelSize, select_plays
from .model_structure import ModelChoice, select_model
from .preisach_candidate import preisach_candidate

MODELS = ("auto", "pi", "pi+creep", *SATURATING)
CANDIDATES = (1, 2, 3, 4, 5, 6, 8, 10)
LAGS = (1, 2, 3)


@dataclasses.dataclass(frozen=True)
class Validation:
    """How an identified model predicts a second record (see [`compare`][piest_jax.compare]).

    **Fields:**

    - `record`: the validation [`Record`][].
    - `raw`: the model run on it from the states named by `state_convention` (a
      [`Comparison`][]).
    - `ic`: the model with the record's own output offset and initial play and lag states
      estimated, nothing else (a [`Comparison`][]); None for the models that saturate, which
      are judged by their raw prediction only.
    - `starts_at_rest`: whether the record's input starts at rest (see `starts_at_rest`); when
      it does not, `raw` depends on states the record does not show.
    - `state_convention`: the states `raw` starts from, in words.
    - `raw_band`, `ic_band`: the 95 % [`prediction_band`][]s of `raw` and `ic` (the IC
      estimate's states and offset taken as known), or None for a fit without a covariance.
    """

    record: Record
    raw: Comparison
    ic: Comparison | None
    starts_at_rest: bool
    state_convention: str
    raw_band: PredictionBand | None = None
    ic_band: PredictionBand | None = None

    def extrapolation(self, identified_range) -> dict:
        """fit.json's `validation_outside_input_range` (the fraction of the record's samples
        whose input lies outside `identified_range`, the identification record's (min, max),
        where the model extrapolates) and `validation_inside_input_range` (`rmse` and, with an
        IC estimate, `rmse_ic` over the samples inside that range; None where none is)."""
        predictions = {"rmse": self.raw.prediction}
        if self.ic is not None:
            predictions["rmse_ic"] = self.ic.prediction
        outside, inside = extrapolation(self.record.u, identified_range, self.record.y, **predictions)
        return {"validation_outside_input_range": outside, "validation_inside_input_range": inside}

    @property
    def band_coverage(self) -> float | None:
        """The fraction of the record's samples inside `raw`'s 95 % measurement band."""
        return None if self.raw_band is None else self.raw_band.coverage(self.record.y)

    @property
    def band_coverage_ic(self) -> float | None:
        """The same for the prediction with the record's initial conditions estimated."""
        return None if self.ic_band is None else self.ic_band.coverage(self.record.y)


@dataclasses.dataclass(frozen=True)
class Identification:
    """The result of [`identify`][piest_jax.identify]: what `piest fit` writes.

    **Fields:**

    - `fit`: the chosen model fitted on the record: a [`PIFit`][] (`fit.model()` is the
      [`HysteresisModel`][]), or for `model="gpi"` / `"preisach"` a [`GPIFit`][] /
      [`PreisachFit`][].
    - `record`: the identification [`Record`][].
    - `selection`: how the size was chosen: a [`ModelSize`][] (`plays="auto"` with
      `model="pi"`), a [`ModelChoice`][] (several structures or sizes tried), or None (one
      model asked for).
    - `validation`: a [`Validation`][] on the second record, or None.
    - `solver`: the solver's name (or an optimistix solver object, as given).
    - `fit_from`: the time from which samples were fitted, or None (all of them).
    - `positive_weights`: whether the weights (a Preisach density) were kept non-negative.
    - `loop`: which way the record's loop runs ([`LoopDirection`][]), or None (not looked at).
      With `positive_weights=None` a clockwise loop was fitted with signed weights.
    """

    fit: PIFit | GPIFit | PreisachFit
    record: Record
    selection: ModelSize | ModelChoice | None = None
    validation: Validation | None = None
    solver: object = "lm"
    fit_from: float | None = None
    positive_weights: bool = True
    loop: LoopDirection | None = None

    @property
    def mask(self) -> np.ndarray | None:
        """(T,) 1 on the fitted samples and 0 on the others, or None when all were fitted."""
        return fit_mask(self.record, self.fit_from)

    def to_json(self) -> dict:
        """The report `piest fit` writes as fit.json.

        **Returns:** a dict of numbers, strings, lists and arrays: the model's keys as
        [`save_model`][] writes them (so [`load_model`][] reads it back), the record's size,
        the fit's RMSE, flags, solver result, standard errors and covariance, the selection and
        the validation. [`write_json`][] writes it; a standard error the record cannot bound is
        infinite there (null in the file).
        """
        f, rec, v = self.fit, self.record, self.validation
        model: HysteresisModel | GeneralizedPI | Preisach
        if isinstance(f, GPIFit | PreisachFit):
            model = f.model
            fit_keys = report_keys(f, self.positive_weights)
        else:
            model = f.model()
            fit_keys = _pi_keys(f, model)
        # The model's keys (schema, structure, parameters, creep) as `save_model` writes them,
        # so that `load_model` reads fit.json back; then how it was fitted.
        report = {
            **model_keys(model),
            "data": rec.source,
            "n_samples": rec.n_samples,
            "dt": rec.dt,
            **fit_keys,
        }
        if not isinstance(f, PreisachFit):
            report["solver"] = {
                "name": _solver_name(self.solver),
                "result": f.result_name,
                "steps": f.n_steps,
                "start_rmse": f.start_rmse,
            }
        report.update(input_extent(rec, self.mask))
        report["positive_weights"] = self.positive_weights
        problem = model.inverse_problem()
        report["invertible"] = problem is None
        if problem is not None:
            report["inverse_problem"] = problem
        if self.loop is not None:
            report["loop"] = self.loop.to_json()
        if self.fit_from is not None:
            report["fit_from"] = self.fit_from
        if self.selection is not None:
            report["selection"] = _selection_keys(self.selection)
        if v is not None:
            report["validate"] = v.record.source
            report["validation_initial_states"] = v.state_convention
            report["validation_rmse"] = float(v.raw.rmse)
        if v is not None and v.ic is not None:
            report["validation_starts_at_rest"] = v.starts_at_rest
            report["validation_rmse_ic"] = float(v.ic.rmse)
            # The fit percentage of the prediction with the record's initial conditions.
            report["validation_fit_percent"] = float(v.ic.fit_percent)
        if v is not None:
            report.update(v.extrapolation(report["input_range"]))
        if v is not None and v.raw_band is not None:
            report["validation_band_coverage"] = v.band_coverage
            if v.ic_band is not None:
                report["validation_band_coverage_ic"] = v.band_coverage_ic
        return report


def _pi_keys(f: PIFit, model) -> dict:
    """fit.json's keys for a PI or PI + creep fit: size, RMSE, flags, covariance, creep."""
    keys = {
        "model": {"structure": model.structure, "n_plays": f.n_plays, "n_lags": f.n_lags},
        "n_plays": f.n_plays,
        "rmse": f.rmse,
        "flagged": f.flagged,
        **_cov.report_keys(f),
    }
    if f.creep is not None:
        keys["creep"] = {
            "time_constants": f.creep.time_constants,
            "weights": f.creep.weights,
            "dt": f.creep.dt,
            # At rest: each lag starts at the first input of whatever record it runs on.
            "starts_at_rest": f.creep.initial_states is None,
        }
        if f.creep.initial_states is not None:
            keys["creep"]["initial_states"] = f.creep.initial_states
    return keys


def _solver_name(solver) -> str:
    return solver if isinstance(solver, str) else type(solver).__name__


def _selection_keys(sel) -> dict:
    if isinstance(sel, ModelSize):
        return {
            "criterion": sel.criterion,
            "candidates": sel.candidates,
            "scores": sel.scores,
            "rejected": sel.rejected,
            "selection_samples": sel.selection_samples,
        }
    # The play counts tried for the plain PI model (the first step of the search), then every
    # structure tried.
    base = [(c, s) for c, s in zip(sel.candidates, sel.scores) if c[1] == sel.candidates[0][1]]
    return {
        "criterion": "holdout",
        "candidates": [c[0] for c, _ in base],
        "scores": [s for _, s in base],
        "models": [
            {"n_plays": c[0], "n_lags": c[1], "score": s, "rejected": c in sel.rejected}
            for c, s in zip(sel.candidates, sel.scores)
        ],
        "selection_samples": sel.selection_samples,
        **({} if sel.preisach is None else {"preisach": sel.preisach.to_json()}),
        **({} if sel.gpi is None else {"gpi": sel.gpi.to_json()}),
    }


@dataclasses.dataclass(frozen=True)
class Plan:
    """What `identify` will try on a record: the fitted samples and the candidates."""

    mask: np.ndarray | None
    plays: tuple
    lags: tuple
    time_constants: tuple | None

    @property
    def n_parameters(self) -> int:
        """The largest model's parameter count, initial states included (for memory checks)."""
        return 3 * (max(self.plays) + max(self.lags)) + 1


def check_options(
    *,
    model="auto",
    plays="auto",
    lags=None,
    time_constants=None,
    candidates=None,
    criterion=None,
    initial_states=None,
    fit_initial_states=False,
    **others,
) -> None:
    """Refuse options that contradict each other, or that the chosen mode would ignore.

    `others` are [`identify`][piest_jax.identify]'s further options by name (`terms`, `grid`,
    `smoothness`, `solver`, `starts`, ...), checked against the models that saturate. Messages
    name options as `name`, which the command line turns into its --name.
    """
    if model not in MODELS:
        raise ValueError(f"unknown `model` {model!r}; choose one of {', '.join(MODELS)}")
    check_saturating(
        dict(
            model=model,
            plays=plays,
            lags=lags,
            time_constants=time_constants,
            candidates=candidates,
            criterion=criterion,
            fit_initial_states=fit_initial_states,
            **others,
        )
    )
    if plays != "auto" and not (isinstance(plays, int | np.integer) and not isinstance(plays, bool) and plays >= 1):
        raise ValueError(f"`plays` must be a positive whole number or 'auto', got {plays!r}")
    if criterion is not None and criterion not in CRITERIA:
        raise ValueError(f"unknown `criterion` {criterion!r}; choose one of {', '.join(CRITERIA)}")
    if fit_initial_states and initial_states is not None:
        raise ValueError("give either `initial_states` or `fit_initial_states`, not both")
    if plays != "auto":
        for given, name in ((candidates, "candidates"), (criterion, "criterion")):
            if given is not None:
                raise ValueError(f"`{name}` is used only by `plays` auto; `plays` {plays} fixes the number of plays")
    if lags is not None:
        if model == "pi":
            raise ValueError("`lags` needs `model` pi+creep or auto, not `model` pi (no creep)")
        if time_constants is not None:
            raise ValueError("give either `lags` or `time_constants` (whose count fixes the lags), not both")
    if model == "pi" and time_constants is not None:
        raise ValueError("`time_constants` needs `model` pi+creep or auto, not `model` pi")
    if criterion == "bic" and model != "pi":
        raise ValueError(
            f"`criterion` bic chooses the plays only; use it with `model` pi "
            f"(`model` {model} chooses by held-out error)"
        )
    for name, values in (("candidates", candidates), ("lags", lags)):
        if values is not None:
            try:
                v = list(_counts(values))
            except TypeError:
                raise ValueError(f"`{name}` must be a whole number or a list of them, got {values!r}") from None
            if (
                not v
                or any(not isinstance(c, int | np.integer) or isinstance(c, bool) or c < 1 for c in v)
                or len(set(v)) != len(v)
            ):
                raise ValueError(f"`{name}` must be distinct positive whole numbers, got {values!r}")


def _counts(values) -> tuple:
    """A count or an iterable of counts, as a tuple (one whole number means just that one)."""
    return (values,) if isinstance(values, int | np.integer) else tuple(values)


def plan(
    record: Record,
    *,
    model="auto",
    plays="auto",
    lags=None,
    time_constants=None,
    candidates=None,
    criterion=None,
    fit_from=None,
    initial_states=None,
    fit_initial_states=False,
) -> Plan:
    """The candidates `identify` tries on `record`, after checking the options against it.

    Raises `ValueError` for a constant input, a `fit_from` past the record's end, time
    constants the record cannot tell apart, or too few samples for every candidate.
    """
    check_options(
        model=model,
        plays=plays,
        lags=lags,
        time_constants=time_constants,
        candidates=candidates,
        criterion=criterion,
        initial_states=initial_states,
        fit_initial_states=fit_initial_states,
    )
    _check_record(record)
    mask = fit_mask(record, fit_from)
    n_used = record.n_samples if mask is None else int(mask.sum())
    candidates = _counts(candidates or CANDIDATES)
    lag_counts = _counts(lags or LAGS)
    if time_constants is not None:
        time_constants = tuple(float(tau) for tau in time_constants)
        _check_time_constants(time_constants, record)
        lag_counts = (len(time_constants),)
    per_play = 3 if fit_initial_states else 2
    lag_choices = {"pi": (0,), "pi+creep": lag_counts}.get(model, (0, *lag_counts))
    used = np.ones(record.n_samples) if mask is None else mask
    if plays == "auto" or len(lag_choices) > 1:
        used = used * holdout_mask(record.n_samples, HOLDOUT)
    n_fit = int(used.sum())
    if plays == "auto":
        fitting = tuple(c for c in candidates if per_play * (c + max(lag_choices)) + 1 <= n_fit)
        if not fitting:
            raise ValueError(
                f"{record.source}: {n_used} samples{'' if mask is None else ' from `fit_from` on'} "
                f"are too few to choose among `candidates` {','.join(map(str, candidates))} (each "
                f"needs {per_play}n + 1 fitted samples, and a creep lag as many as a play)"
            )
        return Plan(mask, fitting, lag_choices, time_constants)
    # Lag counts the held-out part cannot carry are not tried; with none left the single fit
    # names the shortage.
    fits = tuple(k for k in lag_choices if per_play * (plays + k) + 1 <= n_fit)
    return Plan(mask, (int(plays),), fits or lag_choices[:1], time_constants)


def identify(
    record: Record,
    validation: Record | None = None,
    *,
    model: str = "auto",
    plays="auto",
    lags=None,
    time_constants=None,
    candidates=None,
    criterion: str | None = None,
    fit_from: float | None = None,
    solver="lm",
    key=None,
    starts: int = 4,
    positive_weights: bool | None = None,
    initial_states: float | None = None,
    fit_initial_states: bool = False,
    max_threshold: float | None = None,
    max_steps: int = 100,
    terms: int | None = None,
    grid: tuple[int, int] | None = None,
    smoothness: float | None = None,
    quiet: bool = True,
) -> Identification:
    """Choose, fit and validate a model of a measured record: what `piest fit` computes.

    **Arguments:**

    - `record`: the identification [`Record`][]; `validation`: a second record to judge the
      model on (it never takes part in choosing or fitting), or None.
    - `model`: `"auto"` (plain PI or PI + creep, by held-out error: [`select_model`][]; with
      `plays="auto"`, non-negative weights and unfitted initial states also a non-negative
      Preisach model, chosen only where the record determines it: [`PreisachCandidate`][],
      and, where the output saturates, a generalized PI: [`GPICandidate`][]),
      `"pi"`, `"pi+creep"`, or one of the models that saturate: `"gpi"` (a
      [`GeneralizedPI`][], [`fit_gpi`][piest_jax.fit_gpi]; needs `plays`) or `"preisach"` (a
      [`Preisach`][] grid, [`fit_preisach`][piest_jax.fit_preisach]; no `plays`, `solver`,
      `starts`, ...). Options a model would ignore are refused.
    - `plays`: the number of plays, or `"auto"` to choose it among `candidates` (default
      1, 2, 3, 4, 5, 6, 8, 10) by `criterion` (`"holdout"`, the default, or `"bic"` with
      `model="pi"`); candidates the record is too short for are left out.
    - `lags`: the creep lag count, or the counts tried (default 1, 2, 3); `time_constants`:
      starting time constants instead (their count fixes the lags), each between the sampling
      interval and 100 times the record's duration.
    - `fit_from`: fit only the samples at time >= `fit_from` (the earlier ones still drive the
      plays), or None.
    - `positive_weights`: keep the weights (a Preisach density) non-negative (True), or not
      (False); None, the default, decides by the record's loop ([`loop_direction`][]):
      non-negative unless the loop runs clockwise (the output leads the input, as an inverse PI
      does), which non-negative weights cannot shape (they would fit a straight line); a
      `"gpi"` model keeps non-negative weights.
    - `solver`, `key`, `starts` (`n_starts`), `initial_states`, `fit_initial_states`,
      `max_threshold`, `max_steps`: as for [`fit_pi`][].
    - `terms`: `model="gpi"`: the tanh terms of the output function (default 2).
    - `grid`: `model="preisach"`: (half-widths, centres) of the relay grid (default (16, 16));
      `smoothness`: its density's smoothness penalty (default: chosen on held-out blocks);
      `positive_weights` keeps its density non-negative.
    - `quiet`: when False, show a progress bar over the candidates (on a terminal only).

    **Returns:** an [`Identification`][]; its `to_json()` is `piest fit`'s fit.json. Raises
    `ValueError` for options that contradict each other or that the mode would ignore (e.g.
    `candidates` with a fixed `plays`), a constant input, no sample from `fit_from` on, too few
    samples for the candidates, or a validation record sampled at another interval than a
    model with creep was identified at.
    """
    options = dict(
        model=model,
        plays=plays,
        lags=lags,
        time_constants=time_constants,
        candidates=candidates,
        criterion=criterion,
        initial_states=initial_states,
        fit_initial_states=fit_initial_states,
    )
    if validation is not None and not isinstance(validation, Record):
        raise ValueError(f"`validation` must be a Record or None, got {type(validation).__name__}")
    saturating = dict(
        terms=terms,
        grid=grid,
        smoothness=smoothness,
        solver=solver,
        starts=starts,
        positive_weights=positive_weights,
        max_threshold=max_threshold,
        max_steps=max_steps,
    )
    check_options(**options, **saturating)
    _check_record(record)
    loop = loop_direction(record.u, record.y)
    if positive_weights is None:
        # A GPI's plays and output function take non-negative weights only.
        positive_weights = loop.direction != "clockwise" or model == "gpi"
        saturating["positive_weights"] = positive_weights
    if model in SATURATING:
        mask = fit_mask(record, fit_from)
        fit = fit_saturating(
            record,
            mask,
            model=model,
            plays=plays,
            key=key,
            initial_states=initial_states,
            fit_initial_states=fit_initial_states,
            **saturating,
        )
        checked = None
        if validation is not None:
            checked = _validate_saturating(fit, validation, initial_states, fit_initial_states)
        return Identification(fit, record, None, checked, solver, fit_from, positive_weights, loop)
    p = plan(record, fit_from=fit_from, **options)
    fit_options = dict(
        mask=p.mask,
        solver=solver,
        n_starts=starts,
        key=key,
        positive_weights=positive_weights,
        fit_initial_states=fit_initial_states,
        initial_states=initial_states,
        max_threshold=max_threshold,
        max_steps=max_steps,
    )
    if p.time_constants is not None:
        fit_options["time_constants0"] = p.time_constants
    fit, selection = _choose_and_fit(
        record, p, model=model, plays=plays, criterion=criterion or "holdout", quiet=quiet, **fit_options
    )
    checked = None
    if validation is not None and isinstance(fit, GPIFit | PreisachFit):
        checked = _validate_saturating(fit, validation, initial_states, fit_initial_states)
    elif validation is not None:
        checked = _validate(fit, record, validation, initial_states, fit_initial_states)
    return Identification(fit, record, selection, checked, solver, fit_from, positive_weights, loop)


def _choose_and_fit(record, p: Plan, *, model, plays, criterion, quiet, **fit_options):
    """The fitted model and how it was chosen (None when one model was asked for)."""
    u, y = record.u, record.y
    if model == "pi" and plays == "auto":
        sel = select_plays(u, y, p.plays, criterion=criterion, quiet=quiet, **fit_options)
        return sel.fit, sel
    if len(p.plays) == 1 and len(p.lags) == 1:
        return fit_pi(u, y, p.plays[0], n_lags=p.lags[0], dt=record.dt, **fit_options), None
    choice = select_model(u, y, record.dt, p.plays, p.lags, quiet=quiet, **fit_options)
    # Everything left to the choice: a non-negative Preisach model is a candidate too (see
    # `preisach_candidate.py`; not with initial states fitted, which it has no way to fit, nor
    # with signed weights, whose density could not be inverted).
    if (
        model == "auto"
        and plays == "auto"
        and fit_options["positive_weights"]
        and not fit_options["fit_initial_states"]
    ):
        best = dict(zip(choice.candidates, choice.scores))[(choice.n_plays, choice.n_lags)]
        candidate, preisach_fit = preisach_candidate(
            np.asarray(u), np.asarray(y), p.mask, best, initial_states=fit_options["initial_states"]
        )
        # And a generalized PI where the output saturates (`gpi_candidate.py`), against the
        # best model so far.
        gpi, gpi_fit = gpi_candidate(
            np.asarray(u),
            np.asarray(y),
            p.mask,
            candidate.score if candidate.chosen else best,
            initial_states=fit_options["initial_states"],
            n_starts=fit_options["n_starts"],
            key=fit_options["key"],
            max_steps=fit_options["max_steps"],
        )
        if gpi_fit is not None:
            candidate = dataclasses.replace(candidate, chosen=False)
        chosen = next(f for f in (gpi_fit, preisach_fit, choice.fit) if f is not None)
        choice = dataclasses.replace(choice, preisach=candidate, gpi=gpi, fit=chosen)
    return choice.fit, choice


def _validate_saturating(fit: GPIFit | PreisachFit, val: Record, initial_states, fit_initial_states) -> Validation:
    """The raw prediction of `val` and its band (the models that saturate have no IC estimate)."""
    raw, convention = validation_comparison(fit, val, initial_states, fit_initial_states)
    band = None
    if fit.covariance is not None:
        states = None
        if isinstance(fit, GPIFit) and not fit_initial_states:
            states = val.u[0] if initial_states is None else initial_states
        band = prediction_band(fit, val.u, initial_states=states)
    return Validation(val, raw, None, starts_at_rest(val.u), convention, band)


def _validate(fit: PIFit, record, val, initial_states, fit_initial_states) -> Validation:
    if fit.creep is not None and not np.isclose(val.dt, record.dt, rtol=1e-3):
        raise ValueError(
            f"{val.source}: sampled every {val.dt:g}, but the creep was "
            f"identified at {record.dt:g}; use records with the same sampling"
        )
    if fit_initial_states:
        states, convention = fit.initial_states, "fitted (the identification record's)"
    elif initial_states is not None:
        states, convention = initial_states, f"given ({initial_states:g})"
    else:
        states = val.u[0]
        convention = "first input (every play and lag at rest at the validation record's first input)"
    m = fit.model().with_initial_states(states)
    raw = compare(m, val.u, val.y, estimate_initial=False)
    ic = compare(m, val.u, val.y, estimate_initial=True)
    raw_band = ic_band = None
    if fit.covariance is not None:
        # Fitted states keep their uncertainty; states given or taken from the record are known.
        raw_band = prediction_band(fit, val.u, initial_states=None if fit_initial_states else states)
        e = ic.model
        assert isinstance(e, HysteresisModel)  # compare() returns the HysteresisModel it ran
        ic_band = prediction_band(
            fit,
            val.u,
            initial_states=e.pi.initial_states,
            offset=e.offset,
            lag_states=None if e.creep is None else e.creep.initial_states,
        )
    return Validation(val, raw, ic, starts_at_rest(val.u), convention, raw_band, ic_band)


def input_extent(record: Record, mask) -> dict:
    """fit.json's `input_half_range`, `input_range` (where the model has seen data: `piest
    compensate` refuses inputs far outside it), `input_max_rate` (the fastest |du/dt| in the
    record) and `n_fitted_samples`, for any fitted model."""
    u = np.asarray(record.u, np.float64)
    return {
        "input_half_range": 0.5 * float(np.ptp(u)),
        "input_range": [float(u.min()), float(u.max())],
        "input_max_rate": max_rate(record.t, u),
        "n_fitted_samples": record.n_samples if mask is None else int(mask.sum()),
    }


def _check_record(record) -> None:
    if not isinstance(record, Record):
        raise ValueError(f"`record` must be a Record (see load_record), got {type(record).__name__}")
    if np.ptp(record.u) == 0:
        raise ValueError(
            f"{record.source}: the input u is constant ({record.u[0]:g}): it excites "
            "no play, so there is nothing to fit"
        )


def fit_mask(record: Record, fit_from) -> np.ndarray | None:
    """(T,) 1 on the samples at time >= `fit_from`, 0 before; None when `fit_from` is None.
    Raises `ValueError` for a non-finite `fit_from` or one after the record's last sample."""
    if fit_from is None:
        return None
    if not np.isfinite(fit_from):
        raise ValueError(f"`fit_from` must be a finite time, got {fit_from}")
    mask = (record.t >= fit_from).astype(float)
    if not mask.any():
        raise ValueError(
            f"{record.source}: no sample at or after `fit_from` {fit_from:g} (the record ends at t = {record.t[-1]:g})"
        )
    return mask


def _check_time_constants(taus, record: Record) -> None:
    duration = record.t[-1] - record.t[0]
    for tau in taus:
        if not tau > 0:
            raise ValueError(
                f"`time_constants`: {tau:g} is not positive; a creep time constant must be a positive time"
            )
        if tau < record.dt:
            raise ValueError(
                f"`time_constants`: {tau:g} is shorter than the sampling interval "
                f"{record.dt:g}: such a lag cannot be told from the input itself"
            )
        if tau > 100 * duration:
            raise ValueError(
                f"`time_constants`: {tau:g} is over 100 times the record's duration "
                f"{duration:g}: such a lag cannot be told from an offset"
            )


def starts_at_rest(u, fraction: float = 0.01, tolerance: float = 0.01) -> bool:
    """Whether a record starts at rest: its input moves by less than `tolerance` of its range
    over the first `fraction` of the record (at least two samples)."""
    u = np.asarray(u, float)
    head = u[: max(2, int(round(fraction * u.size)))]
    return bool(np.ptp(head) <= tolerance * max(np.ptp(u), np.finfo(float).tiny))
