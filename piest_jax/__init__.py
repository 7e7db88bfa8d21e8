"""piest_jax: Prandtl-Ishlinskii hysteresis in JAX.

Play and stop operators, the PI operator and its analytic inverse, adaptive weight estimation with
persistent-excitation analysis, gradient-based threshold fitting, and model-discrepancy diagnosis.
"""

from ._estimation.batch import BatchStats as BatchStats
from ._estimation.batch import run_batch as run_batch
from ._estimation.certificate import Certificate as Certificate
from ._estimation.certificate import convergence_certificate as convergence_certificate
from ._estimation.certificate import information_form as information_form
from ._estimation.certificate import noise_covariance as noise_covariance
from ._diagnosis.diagnose import diagnose as diagnose
from ._estimation.estimators import AbstractEstimator as AbstractEstimator
from ._estimation.estimators import Estimation as Estimation
from ._estimation.estimators import estimate as estimate
from ._estimation.gradient import NormalisedGradient as NormalisedGradient
from ._diagnosis.hidden import generate as hidden_effect_record
from ._excitation.pe import IndependenceCheck as IndependenceCheck
from ._excitation.pe import assumption1_ratio as assumption1_ratio
from ._excitation.pe import excited_plays as excited_plays
from ._excitation.pe import lemma1_check as lemma1_check
from ._excitation.pe import pe_level as pe_level
from ._excitation.pe import window_starts as window_starts
from ._excitation.pe import windowed_gram as windowed_gram
from ._excitation.pe import windowed_pe_levels as windowed_pe_levels
from ._excitation.pe import windowed_range as windowed_range
from ._operators.pi import inverse as inverse
from ._excitation.draw_metrics import draw_statistics as draw_statistics
from ._excitation.families import draw_case as draw_case
from ._excitation.map_report import summarise as summarise
from ._excitation.map_settings import MapSettings as MapSettings
from ._excitation.map_settings import make_settings as make_settings
from ._excitation.map_settings import numerical_tolerance as numerical_tolerance
from ._excitation.montecarlo import draw_family as draw_family
from ._excitation.montecarlo import draw_keys as draw_keys
from ._excitation.montecarlo import mesh_sharding as mesh_sharding
from ._excitation.montecarlo import pe_map as pe_map
from ._excitation.condition import sharper_condition as sharper_condition
from ._excitation.exact_condition import EventRows as EventRows
from ._excitation.exact_condition import ExactCondition as ExactCondition
from ._excitation.exact_condition import event_rows as event_rows
from ._excitation.exact_condition import exact_condition as exact_condition
from ._excitation.exact_condition import pe_margin as pe_margin
from ._identification.compensate import Compensation as Compensation
from ._identification.compensate import admissible_states as admissible_states
from ._identification.compensate import evaluate_compensation as evaluate_compensation
from ._identification.compensate import feedforward as feedforward
from ._identification.compensate import linear_feedforward as linear_feedforward
from ._identification.fit import PIFit as PIFit
from ._identification.fit import fit_pi as fit_pi
from ._identification.fit import unexcited as unexcited
from ._identification.fit import uniform_pi as uniform_pi
from ._identification.model_size import ModelSize as ModelSize
from ._identification.model_size import select_plays as select_plays
from ._operators.pi import AbstractHysteresisOperator as AbstractHysteresisOperator
from ._operators.pi import PIOperator as PIOperator
from ._operators.play import play as play
from ._operators.play import play_step as play_step
from ._operators.play import stop as stop
from ._estimation.rls import ContinuousRLS as ContinuousRLS
from ._estimation.rls import ForgettingRLS as ForgettingRLS

__version__ = "0.1.0"
