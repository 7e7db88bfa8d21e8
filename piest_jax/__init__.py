"""piest_jax: Prandtl-Ishlinskii hysteresis in JAX.

Play and stop operators, the PI operator and its analytic inverse, adaptive weight estimation with
persistent-excitation analysis, gradient-based threshold fitting, and model-discrepancy diagnosis.
"""

from ._inverse import inverse as inverse
from ._pi import AbstractHysteresisOperator as AbstractHysteresisOperator
from ._pi import PIOperator as PIOperator
from ._play import play as play
from ._play import play_step as play_step
from ._play import stop as stop

__version__ = "0.1.0"
