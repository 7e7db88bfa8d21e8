"""The named effects, one module each, found here and listed in their `listed` order.

Adding an effect is one new module in this folder holding a final subclass of `AbstractEffect`
(`_diagnosis/effect.py`) with the next free `listed` number.
"""

from ..._registry import discover
from ..effect import AbstractEffect

_REGISTERED: tuple[AbstractEffect, ...] = discover(__name__, __path__, AbstractEffect)

EFFECT: dict[str, AbstractEffect] = {e.name: e for e in _REGISTERED}
EFFECTS: tuple[str, ...] = tuple(EFFECT)
# Effects tied to the record they were found on (the unrecorded past before its first sample, a
# drift over its time axis): they explain that record but cannot carry over to another run of the
# device, so a model used on another record leaves them out. The others are functions of the input.
RECORD_SPECIFIC: tuple[str, ...] = tuple(e.name for e in _REGISTERED if e.record_specific)


def chain(names) -> list[AbstractEffect]:
    """The effects named in `names` (a configuration's keys), in signal-chain order."""
    return sorted((EFFECT[n] for n in names), key=lambda e: e.rank)


def check_names(names) -> None:
    """Refuse a name that is not a registered effect, naming the choices."""
    for n in names:
        if n not in EFFECT:
            raise ValueError(f"unknown effect {n!r}; choose from {EFFECTS}")
