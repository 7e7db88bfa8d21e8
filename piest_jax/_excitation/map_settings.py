"""Settings of a Monte Carlo PE map, and the rounding level below which a draw is not PE."""

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .._operators.play import METHODS
from .families import DEFAULT_FAMILIES, family_indices


class MapSettings(NamedTuple):
    """Static settings of a map (hashable: one compiled engine per distinct value).

    **Fields:** `n_samples` T; `n_plays` n; `window` samples per PE window (T0/dt); `stride`
    samples between window starts; `dt` the sampling step; `P0` the RLS initial gain (P0·I);
    `rls_samples` samples the RLS has seen when its error is read; `families` indices into
    `FAMILIES` to draw from; `dtype` the floating type of the whole computation; `play_method`
    how the play bank is computed (`"auto"`, the default: the compiled kernel on a CPU, the
    associative scan on an accelerator; or `"scan"`, `"associative"`, `"kernel"`; all give the
    same outputs to the last bit).
    """

    n_samples: int
    n_plays: int
    window: int
    stride: int
    dt: float
    P0: float
    rls_samples: int
    families: tuple[int, ...]
    dtype: str
    play_method: str = "auto"

    def times(self):
        """The sample times k·dt (T,) every draw of the map is drawn on, in the map's dtype."""
        return jnp.arange(self.n_samples, dtype=jnp.dtype(self.dtype)) * jnp.asarray(self.dt, self.dtype)


def make_settings(
    *,
    n_samples: int,
    n_plays: int = 10,
    window: int | None = None,
    stride: int | None = None,
    dt: float = 2e-3,
    P0: float = 1e6,
    rls_samples: int | None = None,
    families=DEFAULT_FAMILIES,
    dtype=None,
    play_method: str = "auto",
) -> MapSettings:
    """Check and complete the settings of a map.

    **Arguments:** `n_samples` >= 2; `n_plays` >= 1; `window` in [1, n_samples] (default
    n_samples // 5); `stride` >= 1 (default window // 10); `dt` > 0; `P0` > 0; `rls_samples` in
    [1, n_samples] (default n_samples); `families`, names from `FAMILIES` (default
    `DEFAULT_FAMILIES`, the seven non-adversarial ones); `dtype`, float32 or
    float64 (default JAX's default float); `play_method` as in `piest_jax.play`.

    **Returns:** a [`MapSettings`][]. Bad values raise `ValueError` naming the argument.
    """

    def whole(name, v, lo, hi=None):
        if isinstance(v, bool) or not isinstance(v, int | np.integer) or v < lo:
            raise ValueError(f"`{name}` must be a whole number >= {lo}, got {v!r}")
        if hi is not None and v > hi:
            raise ValueError(f"`{name}` ({v}) is longer than the signal ({hi} samples)")
        return int(v)

    T = whole("n_samples", n_samples, 2)
    n = whole("n_plays", n_plays, 1)
    window = whole("window", T // 5 if window is None else window, 1, T)
    stride = whole("stride", max(1, window // 10) if stride is None else stride, 1)
    rls = whole("rls_samples", T if rls_samples is None else rls_samples, 1, T)
    for name, v in (("dt", dt), ("P0", P0)):
        if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
            raise ValueError(f"`{name}` must be a positive finite number, got {v!r}")
    dtype = jnp.dtype(jnp.result_type(float) if dtype is None else dtype)
    if dtype not in (jnp.dtype("float32"), jnp.dtype("float64")):
        raise ValueError(f"`dtype` must be float32 or float64, got {dtype}")
    # JAX's options are attributes its Config object sets at run time, unknown to its annotations.
    if dtype == jnp.dtype("float64") and not jax.config.jax_enable_x64:  # type: ignore[attr-defined]
        raise ValueError("float64 needs jax_enable_x64; enable it or ask for float32")
    if play_method not in METHODS:
        raise ValueError(f"unknown play method {play_method!r}; choose one of {METHODS}")
    idx = family_indices(families)
    return MapSettings(T, n, window, stride, float(dt), float(P0), rls, idx, dtype.name, play_method)


def numerical_tolerance(dtype) -> float:
    """The tolerance on the normalised PE level below which a draw counts as not PE.

    λ_min of a window Gram is only known to about (samples summed) · eps · λ_max, so a normalised
    level below 1e4 · eps (2.2e-12 in float64, 1.2e-3 in float32) is rounding, not excitation.

    **Arguments:** `dtype`, float32 or float64.

    **Returns:** the tolerance, a Python float.
    """
    return 1e4 * float(jnp.finfo(jnp.dtype(dtype)).eps)
