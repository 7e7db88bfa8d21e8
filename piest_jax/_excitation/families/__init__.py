"""Random inputs, threshold sets and initial states for Monte Carlo studies of excitation.

Each input family is one module (`family.py` says what a family states); `registry.py` lists
them; `draw.py` turns a key and a family into a case.
"""

from .draw import draw_case as draw_case
from .draw import draw_initial_states as draw_initial_states
from .draw import draw_input as draw_input
from .draw import draw_thresholds as draw_thresholds
from .draw import draw_weights as draw_weights
from .family import AMPLITUDE_RANGE as AMPLITUDE_RANGE
from .family import FREQUENCY_RANGE as FREQUENCY_RANGE
from .family import AbstractInputFamily as AbstractInputFamily
from .registry import DEFAULT_FAMILIES as DEFAULT_FAMILIES
from .registry import FAMILIES as FAMILIES
from .registry import FAMILY as FAMILY
from .registry import family_indices as family_indices
