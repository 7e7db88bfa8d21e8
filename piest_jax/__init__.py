"""piest_jax: Prandtl-Ishlinskii hysteresis in JAX.

Play and stop operators, the PI operator and its analytic inverse, adaptive weight estimation with
persistent-excitation analysis, gradient-based threshold fitting, and model-discrepancy diagnosis.

Every public name is imported on first use (PEP 562), so `import piest_jax`, and with it
`piest --help`, does not load JAX, SciPy or matplotlib until something needs them.
"""

import importlib
from importlib import metadata as _metadata
from typing import TYPE_CHECKING

try:
    __version__ = _metadata.version("piest_jax")
except _metadata.PackageNotFoundError:  # run from a source tree that was never installed
    __version__ = "0+unknown"

# Public name -> (private module, its name there).
_EXPORTS = {
    # operators
    "AbstractHysteresisOperator": ("._operators.pi", "AbstractHysteresisOperator"),
    "PIOperator": ("._operators.pi", "PIOperator"),
    "inverse": ("._operators.pi", "inverse"),
    "play": ("._operators.play", "play"),
    "play_step": ("._operators.play", "play_step"),
    "stop": ("._operators.play", "stop"),
    "kernel_available": ("._operators.kernel.binding", "available"),
    "kernel_isa": ("._operators.kernel.binding", "isa"),
    "loop_figure": ("._operators.figure", "loop_figure"),
    # estimation
    "AbstractEstimator": ("._estimation.estimators", "AbstractEstimator"),
    "Estimation": ("._estimation.estimators", "Estimation"),
    "estimate": ("._estimation.estimators", "estimate"),
    "ContinuousRLS": ("._estimation.rls", "ContinuousRLS"),
    "ForgettingRLS": ("._estimation.rls", "ForgettingRLS"),
    "NormalisedGradient": ("._estimation.gradient", "NormalisedGradient"),
    "BatchStats": ("._estimation.batch", "BatchStats"),
    "run_batch": ("._estimation.batch", "run_batch"),
    "Certificate": ("._estimation.certificate", "Certificate"),
    "convergence_certificate": ("._estimation.certificate", "convergence_certificate"),
    "information_form": ("._estimation.certificate", "information_form"),
    "noise_covariance": ("._estimation.certificate", "noise_covariance"),
    "OnlineEstimate": ("._estimation.online", "OnlineEstimate"),
    "estimate_record": ("._estimation.online", "estimate_record"),
    "RecordStream": ("._data.stream", "RecordStream"),
    "open_record_stream": ("._data.stream", "open_record_stream"),
    "settled_start": ("._estimation.online", "settled_start"),
    "online_estimate_figure": ("._estimation.online_figure", "online_estimate_figure"),
    # excitation, input signals and the Monte Carlo map
    "time_grid": ("._excitation.signals", "time_grid"),
    "sine": ("._excitation.signals", "sine"),
    "multisine": ("._excitation.signals", "multisine"),
    "triangle": ("._excitation.signals", "triangle"),
    "chirp": ("._excitation.signals", "chirp"),
    "INPUT_FAMILIES": ("._excitation.families", "FAMILIES"),
    "draw_case": ("._excitation.draw", "draw_case"),
    "IndependenceCheck": ("._excitation.pe", "IndependenceCheck"),
    "assumption1_ratio": ("._excitation.pe", "assumption1_ratio"),
    "excited_plays": ("._excitation.pe", "excited_plays"),
    "lemma1_check": ("._excitation.pe", "lemma1_check"),
    "pe_level": ("._excitation.pe", "pe_level"),
    "window_starts": ("._excitation.pe", "window_starts"),
    "windowed_gram": ("._excitation.pe", "windowed_gram"),
    "windowed_pe_levels": ("._excitation.pe", "windowed_pe_levels"),
    "windowed_range": ("._excitation.pe", "windowed_range"),
    "sharper_condition": ("._excitation.condition", "sharper_condition"),
    "EventRows": ("._excitation.exact_condition", "EventRows"),
    "ExactCondition": ("._excitation.exact_condition", "ExactCondition"),
    "event_rows": ("._excitation.exact_condition", "event_rows"),
    "exact_condition": ("._excitation.exact_condition", "exact_condition"),
    "pe_margin": ("._excitation.exact_condition", "pe_margin"),
    "exact_window_pe": ("._excitation.exact_arithmetic", "exact_window_pe"),
    "exact_draw_pe": ("._excitation.exact_arithmetic", "exact_draw_pe"),
    "needs_settling": ("._excitation.settle", "needs_settling"),
    "settle_band": ("._excitation.settle", "settle_band"),
    "InputDesign": ("._excitation.design", "InputDesign"),
    "design_input": ("._excitation.design", "design_input"),
    "excitation_report": ("._excitation.design_compare", "excitation_report"),
    "excitation_figure": ("._excitation.design_compare", "excitation_figure"),
    "draw_statistics": ("._excitation.draw_metrics", "draw_statistics"),
    "summarise": ("._excitation.map_report", "summarise"),
    "PEMap": ("._excitation.map_result", "PEMap"),
    "MapSettings": ("._excitation.map_settings", "MapSettings"),
    "make_settings": ("._excitation.map_settings", "make_settings"),
    "numerical_tolerance": ("._excitation.map_settings", "numerical_tolerance"),
    "draw_family": ("._excitation.montecarlo", "draw_family"),
    "draw_keys": ("._excitation.montecarlo", "draw_keys"),
    "mesh_sharding": ("._excitation.montecarlo", "mesh_sharding"),
    "pe_map": ("._excitation.montecarlo", "pe_map"),
    "pe_map_figure": ("._excitation.map_figure", "pe_map_figure"),
    # identification
    "PIFit": ("._identification.fit", "PIFit"),
    "fit_pi": ("._identification.fit", "fit_pi"),
    "PICoreFit": ("._identification.fit", "PICoreFit"),
    "fit_pi_core": ("._identification.fit", "fit_pi_core"),
    "unexcited": ("._identification.fit", "unexcited"),
    "uniform_pi": ("._identification.fit", "uniform_pi"),
    "ModelSize": ("._identification.model_size", "ModelSize"),
    "select_plays": ("._identification.model_size", "select_plays"),
    "Compensation": ("._identification.compensate", "Compensation"),
    "admissible_states": ("._identification.compensate", "admissible_states"),
    "evaluate_compensation": ("._identification.compensate", "evaluate_compensation"),
    "feedforward": ("._identification.compensate", "feedforward"),
    "linear_feedforward": ("._identification.compensate", "linear_feedforward"),
    "Comparison": ("._identification.compare", "Comparison"),
    "compare": ("._identification.compare", "compare"),
    "fit_percent": ("._identification.compare", "fit_percent"),
    "initial_time_constants": ("._identification.time_constants", "initial_time_constants"),
    "shortest_time_constant": ("._identification.time_constants", "shortest_time_constant"),
    "ModelChoice": ("._identification.model_structure", "ModelChoice"),
    "select_model": ("._identification.model_structure", "select_model"),
    "PreisachCandidate": ("._identification.preisach_candidate", "PreisachCandidate"),
    "GPICandidate": ("._identification.gpi_candidate", "GPICandidate"),
    "saturation_gate": ("._identification.gpi_candidate", "saturation_gate"),
    "Identification": ("._identification.identify", "Identification"),
    "Validation": ("._identification.identify", "Validation"),
    "identify": ("._identification.identify", "identify"),
    "LoopDirection": ("._identification.loop", "LoopDirection"),
    "loop_direction": ("._identification.loop", "loop_direction"),
    "fit_figure": ("._identification.figures", "fit_figure"),
    "PredictionBand": ("._identification.band", "PredictionBand"),
    "prediction_band": ("._identification.band", "prediction_band"),
    "compensation_figure": ("._identification.figures", "compensation_figure"),
    # model components
    "AbstractHysteresisModel": ("._models.model", "AbstractHysteresisModel"),
    "Creep": ("._models.creep", "Creep"),
    "HysteresisModel": ("._models.composite", "HysteresisModel"),
    "Preisach": ("._models.preisach", "Preisach"),
    "GeneralizedPI": ("._models.gpi", "GeneralizedPI"),
    "GPIFit": ("._identification.fit_gpi", "GPIFit"),
    "fit_gpi": ("._identification.fit_gpi", "fit_gpi"),
    "PreisachFit": ("._identification.fit_preisach", "PreisachFit"),
    "fit_preisach": ("._identification.fit_preisach", "fit_preisach"),
    "save_model": ("._identification.model_file", "save_model"),
    "load_model": ("._identification.model_file", "load_model"),
    # diagnosis
    "diagnose": ("._diagnosis.diagnose", "diagnose"),
    "Diagnosis": ("._diagnosis.diagnosis", "Diagnosis"),
    "DiagnosisValidation": ("._diagnosis.diagnosis", "DiagnosisValidation"),
    "diagnosis_figure": ("._diagnosis.figure", "diagnosis_figure"),
    "EFFECTS": ("._diagnosis.effects", "EFFECTS"),
    "noise_std": ("._diagnosis.scaling", "noise_std"),
    "hidden_effect_record": ("._diagnosis.hidden", "generate"),
    "hidden_effect_key": ("._diagnosis.hidden", "record_key"),
    # data
    "Record": ("._data.record", "Record"),
    "DataError": ("._data.record", "DataError"),
    "load_record": ("._data.record", "load_record"),
    "datasets": ("._data.record", "datasets"),
    "dataset_path": ("._data.record", "dataset_path"),
    "load_dataset": ("._data.record", "load_dataset"),
    # reports
    "write_json": ("._report", "write_json"),
    "save_figure": ("._report", "save_figure"),
    # the command line, in-process
    "run_cli": ("._cli", "main"),
}
# Public submodules.
_SUBMODULES = ("paper",)

__all__ = sorted([*_EXPORTS, *_SUBMODULES])


def __getattr__(name: str):
    if name in _SUBMODULES:
        return importlib.import_module(f".{name}", __name__)
    try:
        module, attr = _EXPORTS[name]
    except KeyError:
        raise AttributeError(f"module 'piest_jax' has no attribute {name!r}") from None
    value = getattr(importlib.import_module(module, __name__), attr)
    globals()[name] = value  # the next lookup is a plain attribute access
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})


if TYPE_CHECKING:  # what type checkers and editors see; at run time `__getattr__` imports
    from . import paper as paper
    from ._cli import main as run_cli  # noqa: F401
    from ._data.record import DataError as DataError
    from ._data.record import Record as Record
    from ._data.record import dataset_path as dataset_path
    from ._data.record import datasets as datasets
    from ._data.record import load_dataset as load_dataset
    from ._data.record import load_record as load_record
    from ._data.stream import RecordStream as RecordStream
    from ._data.stream import open_record_stream as open_record_stream
    from ._diagnosis.diagnose import diagnose as diagnose
    from ._diagnosis.diagnosis import Diagnosis as Diagnosis
    from ._diagnosis.diagnosis import DiagnosisValidation as DiagnosisValidation
    from ._diagnosis.effects import EFFECTS as EFFECTS
    from ._diagnosis.figure import diagnosis_figure as diagnosis_figure
    from ._diagnosis.hidden import generate as hidden_effect_record  # noqa: F401
    from ._diagnosis.hidden import record_key as hidden_effect_key  # noqa: F401
    from ._diagnosis.scaling import noise_std as noise_std
    from ._estimation.batch import BatchStats as BatchStats
    from ._estimation.batch import run_batch as run_batch
    from ._estimation.certificate import Certificate as Certificate
    from ._estimation.certificate import convergence_certificate as convergence_certificate
    from ._estimation.certificate import information_form as information_form
    from ._estimation.certificate import noise_covariance as noise_covariance
    from ._estimation.estimators import AbstractEstimator as AbstractEstimator
    from ._estimation.estimators import Estimation as Estimation
    from ._estimation.estimators import estimate as estimate
    from ._estimation.gradient import NormalisedGradient as NormalisedGradient
    from ._estimation.online import OnlineEstimate as OnlineEstimate
    from ._estimation.online import estimate_record as estimate_record
    from ._estimation.online import settled_start as settled_start
    from ._estimation.online_figure import online_estimate_figure as online_estimate_figure
    from ._estimation.rls import ContinuousRLS as ContinuousRLS
    from ._estimation.rls import ForgettingRLS as ForgettingRLS
    from ._excitation.condition import sharper_condition as sharper_condition
    from ._excitation.design import InputDesign as InputDesign
    from ._excitation.design import design_input as design_input
    from ._excitation.design_compare import excitation_figure as excitation_figure
    from ._excitation.design_compare import excitation_report as excitation_report
    from ._excitation.draw import draw_case as draw_case
    from ._excitation.draw_metrics import draw_statistics as draw_statistics
    from ._excitation.exact_arithmetic import exact_draw_pe as exact_draw_pe
    from ._excitation.exact_arithmetic import exact_window_pe as exact_window_pe
    from ._excitation.exact_condition import EventRows as EventRows
    from ._excitation.exact_condition import ExactCondition as ExactCondition
    from ._excitation.exact_condition import event_rows as event_rows
    from ._excitation.exact_condition import exact_condition as exact_condition
    from ._excitation.exact_condition import pe_margin as pe_margin
    from ._excitation.families import FAMILIES as INPUT_FAMILIES  # noqa: F401
    from ._excitation.map_figure import pe_map_figure as pe_map_figure
    from ._excitation.map_report import summarise as summarise
    from ._excitation.map_result import PEMap as PEMap
    from ._excitation.map_settings import MapSettings as MapSettings
    from ._excitation.map_settings import make_settings as make_settings
    from ._excitation.map_settings import numerical_tolerance as numerical_tolerance
    from ._excitation.montecarlo import draw_family as draw_family
    from ._excitation.montecarlo import draw_keys as draw_keys
    from ._excitation.montecarlo import mesh_sharding as mesh_sharding
    from ._excitation.montecarlo import pe_map as pe_map
    from ._excitation.pe import IndependenceCheck as IndependenceCheck
    from ._excitation.pe import assumption1_ratio as assumption1_ratio
    from ._excitation.pe import excited_plays as excited_plays
    from ._excitation.pe import lemma1_check as lemma1_check
    from ._excitation.pe import pe_level as pe_level
    from ._excitation.pe import window_starts as window_starts
    from ._excitation.pe import windowed_gram as windowed_gram
    from ._excitation.pe import windowed_pe_levels as windowed_pe_levels
    from ._excitation.pe import windowed_range as windowed_range
    from ._excitation.settle import needs_settling as needs_settling
    from ._excitation.settle import settle_band as settle_band
    from ._excitation.signals import chirp as chirp
    from ._excitation.signals import multisine as multisine
    from ._excitation.signals import sine as sine
    from ._excitation.signals import time_grid as time_grid
    from ._excitation.signals import triangle as triangle
    from ._identification.band import PredictionBand as PredictionBand
    from ._identification.band import prediction_band as prediction_band
    from ._identification.compare import Comparison as Comparison
    from ._identification.compare import compare as compare
    from ._identification.compare import fit_percent as fit_percent
    from ._identification.compensate import Compensation as Compensation
    from ._identification.compensate import admissible_states as admissible_states
    from ._identification.compensate import evaluate_compensation as evaluate_compensation
    from ._identification.compensate import feedforward as feedforward
    from ._identification.compensate import linear_feedforward as linear_feedforward
    from ._identification.figures import compensation_figure as compensation_figure
    from ._identification.figures import fit_figure as fit_figure
    from ._identification.fit import PICoreFit as PICoreFit
    from ._identification.fit import PIFit as PIFit
    from ._identification.fit import fit_pi as fit_pi
    from ._identification.fit import fit_pi_core as fit_pi_core
    from ._identification.fit import unexcited as unexcited
    from ._identification.fit import uniform_pi as uniform_pi
    from ._identification.fit_gpi import GPIFit as GPIFit
    from ._identification.fit_gpi import fit_gpi as fit_gpi
    from ._identification.fit_preisach import PreisachFit as PreisachFit
    from ._identification.fit_preisach import fit_preisach as fit_preisach
    from ._identification.gpi_candidate import GPICandidate as GPICandidate
    from ._identification.gpi_candidate import saturation_gate as saturation_gate
    from ._identification.identify import Identification as Identification
    from ._identification.identify import Validation as Validation
    from ._identification.identify import identify as identify
    from ._identification.loop import LoopDirection as LoopDirection
    from ._identification.loop import loop_direction as loop_direction
    from ._identification.model_file import load_model as load_model
    from ._identification.model_file import save_model as save_model
    from ._identification.model_size import ModelSize as ModelSize
    from ._identification.model_size import select_plays as select_plays
    from ._identification.model_structure import ModelChoice as ModelChoice
    from ._identification.model_structure import select_model as select_model
    from ._identification.preisach_candidate import PreisachCandidate as PreisachCandidate
    from ._identification.time_constants import initial_time_constants as initial_time_constants
    from ._identification.time_constants import shortest_time_constant as shortest_time_constant
    from ._models.composite import HysteresisModel as HysteresisModel
    from ._models.creep import Creep as Creep
    from ._models.gpi import GeneralizedPI as GeneralizedPI
    from ._models.model import AbstractHysteresisModel as AbstractHysteresisModel
    from ._models.preisach import Preisach as Preisach
    from ._operators.figure import loop_figure as loop_figure
    from ._operators.kernel.binding import available as kernel_available  # noqa: F401
    from ._operators.kernel.binding import isa as kernel_isa  # noqa: F401
    from ._operators.pi import AbstractHysteresisOperator as AbstractHysteresisOperator
    from ._operators.pi import PIOperator as PIOperator
    from ._operators.pi import inverse as inverse
    from ._operators.play import play as play
    from ._operators.play import play_step as play_step
    from ._operators.play import stop as stop
    from ._report import save_figure as save_figure
    from ._report import write_json as write_json
