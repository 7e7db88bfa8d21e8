"""The input families, one module each, registered here in the order maps list them.

Adding a family is one new module (a final subclass of `AbstractInputFamily`) and one line below.
"""

import numpy as np

from .chirp import Chirp
from .decaying import Decaying
from .family import AbstractInputFamily
from .multisine import Multisine
from .nested import Nested
from .noise import Noise
from .ramp import Ramp
from .sine import Sine
from .steps import Steps
from .touch import Touch
from .triangle import Triangle

_REGISTERED: tuple[AbstractInputFamily, ...] = (
    Sine(),
    Multisine(),
    Noise(),
    Chirp(),
    Triangle(),
    Decaying(),
    Steps(),
    Ramp(),
    Touch(),
    Nested(),
)

FAMILY: dict[str, AbstractInputFamily] = {f.name: f for f in _REGISTERED}
FAMILIES: tuple[str, ...] = tuple(FAMILY)
# The families a map draws from unless told otherwise; the adversarial ones (cases for the exact
# excitation condition, docs/excitation_condition.md) are asked for by name.
DEFAULT_FAMILIES: tuple[str, ...] = tuple(f.name for f in _REGISTERED if not f.adversarial)


def family_indices(families) -> tuple[int, ...]:
    """Family names or indices as a tuple of indices into `FAMILIES`; ValueError for unknown ones."""
    if isinstance(families, str):
        families = (families,)
    out = []
    for f in families:
        if isinstance(f, str) and f in FAMILIES:
            out.append(FAMILIES.index(f))
        elif isinstance(f, int | np.integer) and not isinstance(f, bool) and 0 <= f < len(FAMILIES):
            out.append(int(f))
        else:
            raise ValueError(f"unknown input family {f!r}; choose from {FAMILIES}")
    if not out:
        raise ValueError(f"no input family given; choose from {FAMILIES}")
    return tuple(out)
