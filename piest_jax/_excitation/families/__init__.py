"""The input families, one module each, found here and listed in their `listed` order.

Adding a family is one new module in this folder holding a final subclass of
`AbstractInputFamily` (`_excitation/family.py`) with the next free `listed` number.
"""

import numpy as np

from ..._registry import discover
from ..family import AbstractInputFamily

_REGISTERED: tuple[AbstractInputFamily, ...] = discover(__name__, __path__, AbstractInputFamily)

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
