"""The result of a diagnosis: what [`diagnose`][piest_jax.diagnose] found, typed, and the report
`piest diagnose` writes from it (`to_json()` is report.json, less the keys the command adds)."""

import copy
import dataclasses
from collections.abc import Iterator, Mapping

import numpy as np

from .._data.record import Record
from .._identification.loop import LoopDirection
from .effects import EFFECT


@dataclasses.dataclass(frozen=True, eq=False)
class DiagnosisValidation:
    """Both models of a [`Diagnosis`][piest_jax.Diagnosis] run on a second record of the device.

    Only the transferable effects are used there (`effects_used`): the record-specific ones
    belong to the identification record.

    **Fields:**

    - `record`: the validation [`Record`][].
    - `baseline_rmse`, `final_rmse`: the plain PI model and the model with the named effects,
      each run from rest (*raw*).
    - `baseline_rmse_ic`, `final_rmse_ic`: the same with the record's output offset, the plays'
      initial states and the creep lags' states estimated on it, everything else fixed.
    - `baseline_fit_percent`, `final_fit_percent`, `baseline_fit_percent_ic`,
      `final_fit_percent_ic`: the fit percentages 100 (1 - ||e|| / ||y - mean y||) of the four.
    - `initial_conditions`: `{"baseline": ..., "final": ...}`, what was estimated for each model
      (`offset`, `history_turning_points`, `<effect>_states`).
    - `noise_std_estimate`: the validation record's 7-sample noise floor
      ([`noise_std`][piest_jax.noise_std] of its output).
    - `baseline_rmse_offset_removed`, `final_rmse_offset_removed`: the raw RMSEs with each
      model's mean residual removed (a sensor zero that moved between runs).
    - `effects_used`: the transferable effects, in the order named.
    - `outside_input_range`: the fraction of the record's samples whose input lies outside the
      identification record's input range, where every model extrapolates.
    - `inside_input_range`: the four RMSEs above (`baseline_rmse`, `final_rmse`,
      `baseline_rmse_ic`, `final_rmse_ic`) over the samples inside that range only (None for
      one with no sample inside).
    - `baseline_prediction`, `final_prediction`: (T,) the raw predictions.
    """

    record: Record
    baseline_rmse: float
    final_rmse: float
    baseline_rmse_ic: float
    final_rmse_ic: float
    baseline_fit_percent: float
    final_fit_percent: float
    baseline_fit_percent_ic: float
    final_fit_percent_ic: float
    initial_conditions: dict
    noise_std_estimate: float
    baseline_rmse_offset_removed: float
    final_rmse_offset_removed: float
    effects_used: list
    outside_input_range: float
    inside_input_range: dict
    baseline_prediction: np.ndarray
    final_prediction: np.ndarray

    def to_json(self) -> dict:
        """The `validation` block of report.json.

        **Returns:** a new dict of numbers, strings and lists: every field but the record and
        the predictions.
        """
        return {
            f.name: copy.deepcopy(getattr(self, f.name))
            for f in dataclasses.fields(self)
            if f.name not in ("record", "baseline_prediction", "final_prediction")
        }


@dataclasses.dataclass(frozen=True, eq=False)
class Diagnosis(Mapping):
    """The result of [`diagnose`][piest_jax.diagnose]: the effects a plain PI model misses on a
    record, how much each model explains, and the predictions behind the figure.

    It is also a read-only mapping, and that mapping view is the JSON report: `d["effects"]`,
    `"validation" in d`, `d.get(...)`, `dict(d)` and iteration over keys all read
    `d.to_json()` (report.json's keys, less those `piest diagnose` adds). Two diagnoses compare
    equal when their reports do.

    **Fields:**

    - `record`: the identification [`Record`][].
    - `effects`: the effects named, in the order they were named.
    - `baseline_rmse`, `final_rmse`: the RMSE on the whole record of the plain PI model and of
      the model with the named effects (after the joint refinement, when it was kept).
    - `noise_std_estimate`: the noise floor the search judged by, from the final model's
      residual: the larger of the output's 7-sample floor ([`noise_std`][piest_jax.noise_std])
      and the residual's floor on every m-th sample, the local cubic spanning up to the
      input's short time scale, so that noise correlated over several samples (coloured
      sensor noise) counts with its whole variance.
    - `parameters`: `{effect: {name: value}}` for the named effects, after refinement.
    - `refinement`: `{"model_base": ..., "model_final": ...}`: the solver's result, steps, RMSE
      before and after, and which fit was kept (empty without a solver).
    - `rounds`: per round of the search, the current held-out RMSE, each candidate's held-out
      RMSE, score and significance, the best candidate and whether it was named; the first
      round's `untried` says which candidates the record cannot show, and why.
    - `pruned`: effects named and then dropped as made redundant by a later one.
    - `heldout_baseline_rmse`, `heldout_final_rmse`: the held-out-block RMSEs of the search.
    - `search_step`: the search ran on every `search_step`-th sample.
    - `where`: where the plain model's residual is structured: dicts with `kind` (`window`,
      `regime`, `correlation`, ...), `name`, `structured` and the RMS, its ratio to the noise or
      the correlation; structured places first.
    - `baseline_prediction`, `final_prediction`: (T,) both models on the record.
    - `validation`: a [`DiagnosisValidation`][piest_jax.DiagnosisValidation], or None.
    - `uncertainty`: the named effects' numbers (as in `parameters`, by dotted name such as
      `delay.delay_s` or `creep.time_constants_s[0]`) and the final model's offset with their
      standard errors (`values`, `std_errors`, `undetermined`, `method`, `samples`: the
      Newey-West estimate from the refined model's Jacobian, as `fit_pi` gives its own); None
      when no effect is named.
    - `loop`: which way the record's loop runs ([`LoopDirection`][piest_jax.LoopDirection]).
      Non-negative play weights shape counterclockwise loops only; on a clockwise one (the output
      leads the input, as an inverse PI does) every model of the diagnosis, the plain one
      included, takes signed play weights, as `piest fit` does.

    **Properties:** `transferable_effects` (functions of the input, which carry over to another
    record), `record_specific_effects` (tied to this record: its unrecorded past, its drift),
    `candidates` (the first round's scores) and `n_samples`.
    """

    record: Record
    effects: list
    baseline_rmse: float
    final_rmse: float
    noise_std_estimate: float
    parameters: dict
    refinement: dict
    rounds: list
    pruned: list
    heldout_baseline_rmse: float
    heldout_final_rmse: float
    search_step: int
    where: list
    baseline_prediction: np.ndarray
    final_prediction: np.ndarray
    validation: DiagnosisValidation | None = None
    uncertainty: dict | None = None
    loop: LoopDirection | None = None

    @property
    def transferable_effects(self) -> list:
        """The named effects that are functions of the input, in the order named."""
        return [e for e in self.effects if not EFFECT[e].record_specific]

    @property
    def record_specific_effects(self) -> list:
        """The named effects tied to this record (its unrecorded past, its drift over time)."""
        return [e for e in self.effects if EFFECT[e].record_specific]

    @property
    def candidates(self) -> dict:
        """The first round's held-out RMSE, score and significance of every candidate."""
        return {k: dict(v) for k, v in self.rounds[0]["candidates"].items()} if self.rounds else {}

    @property
    def n_samples(self) -> int:
        """The identification record's number of samples."""
        return self.record.n_samples

    def to_json(self) -> dict:
        """The report `piest diagnose` writes as report.json, less the keys the command adds
        (`data`, the record's `time_unit` and `segment`, the validation's `data`).

        **Returns:** a new dict of numbers, strings and lists, in report.json's order:
        `effects`, `transferable_effects`, `record_specific_effects`, `baseline_rmse`,
        `final_rmse`, `noise_std_estimate`, `candidates`, `parameters`, `uncertainty` (when an
        effect is named), `refinement`, `rounds`,
        `pruned`, `heldout` (`baseline_rmse`, `final_rmse`), `n_samples`, `search_step`,
        `where`, `loop` (`direction`, `score`) and, with a validation record, `validation`.
        """
        report = {
            "effects": list(self.effects),
            "transferable_effects": self.transferable_effects,
            "record_specific_effects": self.record_specific_effects,
            "baseline_rmse": self.baseline_rmse,
            "final_rmse": self.final_rmse,
            "noise_std_estimate": self.noise_std_estimate,
            "candidates": copy.deepcopy(self.candidates),
            "parameters": copy.deepcopy(self.parameters),
            **({"uncertainty": copy.deepcopy(self.uncertainty)} if self.uncertainty is not None else {}),
            "refinement": copy.deepcopy(self.refinement),
            "rounds": copy.deepcopy(self.rounds),
            "pruned": list(self.pruned),
            "heldout": {"baseline_rmse": self.heldout_baseline_rmse, "final_rmse": self.heldout_final_rmse},
            "n_samples": self.n_samples,
            "search_step": self.search_step,
            "where": copy.deepcopy(self.where),
        }
        if self.loop is not None:
            report["loop"] = self.loop.to_json()
        if self.validation is not None:
            report["validation"] = self.validation.to_json()
        return report

    def figure(self):
        """Residuals and loops before and after; see [`diagnosis_figure`][piest_jax.diagnosis_figure].

        **Returns:** a `matplotlib.figure.Figure`.
        """
        from .figure import diagnosis_figure

        return diagnosis_figure(self)

    # The mapping view is the JSON report (see the class docstring).
    def __getitem__(self, key):
        return self.to_json()[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self.to_json())

    def __len__(self) -> int:
        return len(self.to_json())

    def __contains__(self, key) -> bool:
        return key in self.to_json()

    def __repr__(self) -> str:
        return (
            f"Diagnosis(effects={self.effects!r}, baseline_rmse={self.baseline_rmse:.4g}, "
            f"final_rmse={self.final_rmse:.4g}, validation={self.validation is not None})"
        )
