"""What an input family is: a pure function from uniform draws to one input signal.

Every random number of a case comes from ONE call of the generator: the family's parameters,
then the thresholds, initial states and weights, each reading its own slice of one uniform
vector. Each separate call would be a separate unrolled hash in the compiled program, and
compiling those dominates a small map. So a family states how many uniforms it reads
(`n_uniforms`) and maps them to an input (`input`); the draw functions (`draw.py`) do the rest.
The families themselves are one module each in `families/`.

Amplitudes are drawn relative to the largest threshold r_max, log-uniform over
[`AMPLITUDE_RANGE`], so a map covers both sides of Assumption 1 (peak-to-peak >= 2 r_max).
Frequencies are log-uniform over [`FREQUENCY_RANGE`] Hz on a record of `duration` seconds, so some
inputs are slower than a window and some much faster.
"""

from typing import ClassVar

import jax.numpy as jnp
from jaxtyping import Array

AMPLITUDE_RANGE = (0.3, 4.0)
FREQUENCY_RANGE = (0.2, 5.0)


def log_uniform(v, lo, hi):
    """Map uniform draws v in [0, 1) to a log-uniform law on [lo, hi]."""
    return jnp.exp(jnp.log(lo) + v * (jnp.log(hi) - jnp.log(lo)))


def common(v, r_max):
    """Amplitude, frequency, offset and phase shared by the periodic families, from v[:4]."""
    amplitude = r_max * log_uniform(v[0], *AMPLITUDE_RANGE)
    frequency = log_uniform(v[1], *FREQUENCY_RANGE)
    offset = r_max * (2 * v[2] - 1)
    phase = 2 * jnp.pi * v[3]
    return amplitude, frequency, offset, phase


class AbstractInputFamily:
    """A family of random inputs. Concrete families are final classes, one module each in `families/`."""

    name: ClassVar[str]
    # Its place in the registry's listing (the index a map's settings record): a new family takes
    # the next free number.
    listed: ClassVar[int]
    # Asked for by name only: an adversarial case for the exact excitation condition
    # (docs/excitation_condition.md), not part of a map's default mix.
    adversarial: ClassVar[bool] = False

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        missing = [a for a in ("name", "listed") if not hasattr(cls, a)]
        if missing:
            raise TypeError(f"input family {cls.__name__} does not define {', '.join(missing)}")

    def __repr__(self) -> str:
        return f"<input family {self.name}>"

    def n_uniforms(self, T: int) -> int:
        """How many uniforms `input` reads for a record of T samples."""
        raise NotImplementedError

    def input(self, v: Array, t: Array, r: Array) -> Array:
        """The input (T,) from uniforms `v`, the time grid `t` and the thresholds `r` (n,)."""
        raise NotImplementedError
