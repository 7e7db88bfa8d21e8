"""The uncertainty fields every fit result carries: its parameters' names, values, covariance and
standard errors, which of them the record does not determine, and the residuals' spread.

One definition for [`PIFit`][], [`GPIFit`][piest_jax.GPIFit] and
[`PreisachFit`][piest_jax.PreisachFit]; each fit fills them from its own covariance module
(`covariance.py`, `gpi_covariance.py`, `preisach_covariance.py`). The fields are keyword-only, so
a fit's own fields come first when it is built.
"""

import equinox as eqx
from jaxtyping import Array, Bool, Float

from .._custom_types import Scalar
from .covariance import flagged_names


class Uncertainty(eqx.Module):
    """The covariance fields of a fit (all None, and no names, when it was fitted without one).

    **Fields:** `parameter_names`, `parameter_values` (p,), `covariance` (p, p), `std_errors`
    (p,), `undetermined` (p,) bool, `covariance_method`, `residual_std`; see [`PIFit`][].
    """

    parameter_names: tuple = eqx.field(static=True, default=(), kw_only=True)
    parameter_values: Float[Array, " params"] | None = eqx.field(default=None, kw_only=True)
    covariance: Float[Array, "params params"] | None = eqx.field(default=None, kw_only=True)
    std_errors: Float[Array, " params"] | None = eqx.field(default=None, kw_only=True)
    undetermined: Bool[Array, " params"] | None = eqx.field(default=None, kw_only=True)
    covariance_method: str | None = eqx.field(static=True, default=None, kw_only=True)
    residual_std: Scalar | float | None = eqx.field(default=None, kw_only=True)

    @property
    def undetermined_names(self) -> tuple:
        """The names of the parameters the record does not determine."""
        return flagged_names(self.parameter_names, self.undetermined)
