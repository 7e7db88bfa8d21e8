"""Shape aliases used across the package, in one place.

They document shapes in signatures and are not checked at run time, in the library or in the
tests: the public functions validate their inputs themselves and raise `ValueError`s that name the
argument and the problem (tested message by message), which a runtime type checker (jaxtyping's
import hook with beartype) would pre-empt with its own `TypeCheckError`.
"""

from typing import TypeAlias

from jaxtyping import Array, ArrayLike, Float

Scalar: TypeAlias = Float[Array, ""]
ScalarLike: TypeAlias = float | Float[ArrayLike, ""]
Signal: TypeAlias = Float[Array, " time"]
SignalLike: TypeAlias = Float[ArrayLike, " time"]
Thresholds: TypeAlias = Float[Array, " plays"]
ThresholdsLike: TypeAlias = float | Float[ArrayLike, " plays"] | Float[ArrayLike, ""]
Weights: TypeAlias = Float[Array, " plays"]
States: TypeAlias = Float[Array, " plays"]
Regressor: TypeAlias = Float[Array, "time plays"]
Gram: TypeAlias = Float[Array, "plays plays"]
