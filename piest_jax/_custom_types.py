"""Shape aliases used across the package, in one place.

They document shapes in signatures; runtime checking is switched on in the tests only.
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
