"""piest_jax: Prandtl-Ishlinskii hysteresis in JAX.

Play and stop operators, the PI operator and its analytic inverse, adaptive weight estimation with
persistent-excitation analysis, gradient-based threshold fitting, and model-discrepancy diagnosis.
"""

from ._batch import BatchStats as BatchStats
from ._batch import run_batch as run_batch
from ._certificate import Certificate as Certificate
from ._certificate import convergence_certificate as convergence_certificate
from ._certificate import information_form as information_form
from ._certificate import noise_covariance as noise_covariance
from ._diagnose import diagnose as diagnose
from ._estimators import AbstractEstimator as AbstractEstimator
from ._estimators import Estimation as Estimation
from ._estimators import estimate as estimate
from ._gradient import NormalisedGradient as NormalisedGradient
from ._hidden import generate as hidden_effect_record
from ._excitation import IndependenceCheck as IndependenceCheck
from ._excitation import assumption1_ratio as assumption1_ratio
from ._excitation import excited_plays as excited_plays
from ._excitation import lemma1_check as lemma1_check
from ._excitation import pe_level as pe_level
from ._excitation import window_starts as window_starts
from ._excitation import windowed_gram as windowed_gram
from ._excitation import windowed_pe_levels as windowed_pe_levels
from ._excitation import windowed_range as windowed_range
from ._inverse import inverse as inverse
from ._draw_metrics import draw_statistics as draw_statistics
from ._families import draw_case as draw_case
from ._map_report import summarise as summarise
from ._map_settings import MapSettings as MapSettings
from ._map_settings import make_settings as make_settings
from ._map_settings import numerical_tolerance as numerical_tolerance
from ._montecarlo import draw_family as draw_family
from ._montecarlo import draw_keys as draw_keys
from ._montecarlo import mesh_sharding as mesh_sharding
from ._montecarlo import pe_map as pe_map
from ._window_stats import sharper_condition as sharper_condition
from ._compensate import Compensation as Compensation
from ._compensate import admissible_states as admissible_states
from ._compensate import evaluate_compensation as evaluate_compensation
from ._compensate import feedforward as feedforward
from ._compensate import linear_feedforward as linear_feedforward
from ._fit import PIFit as PIFit
from ._fit import fit_pi as fit_pi
from ._fit import unexcited as unexcited
from ._fit import uniform_pi as uniform_pi
from ._modelsize import ModelSize as ModelSize
from ._modelsize import select_plays as select_plays
from ._pi import AbstractHysteresisOperator as AbstractHysteresisOperator
from ._pi import PIOperator as PIOperator
from ._play import play as play
from ._play import play_step as play_step
from ._play import stop as stop
from ._rls import ContinuousRLS as ContinuousRLS
from ._rls import ForgettingRLS as ForgettingRLS

__version__ = "0.1.0"
