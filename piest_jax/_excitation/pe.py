"""Persistent excitation of the play regressor: Definition 1, Assumption 1 and Lemma 1 of the paper.

All functions take one sampled regressor H (T, n) or one input u (T,); batch them with `jax.vmap`.
A window of `window` samples stands for the paper's interval [t0, t0 + T0]; windows start every
`stride` samples, so `stride=1` checks every t0 the sampling can see. Integrals over a window are
sample means, (1/T0)∫ H Hᵀ dt ≈ mean_k h_k h_kᵀ, which is exact for the zero-order hold of the data.
"""

from typing import NamedTuple

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from .. import _checks
from .._custom_types import Regressor, Scalar, SignalLike


def _regressor(H, name: str = "H") -> Array:
    H = _checks.as_float_array(H, name)
    if H.ndim != 2:
        raise ValueError(
            f"`{name}` must be one regressor of shape (T, n), got shape {H.shape}; batch several with jax.vmap"
        )
    if H.shape[0] < 1 or H.shape[1] < 1:
        raise ValueError(f"`{name}` is empty: shape {H.shape}")
    return _checks.finite(H, name)


def _window_args(T: int, window, stride) -> tuple[int, int, int]:
    if not _checks.is_whole(window):
        raise ValueError(f"`window` must be a whole number of samples, got {window!r}")
    if not _checks.is_whole(stride):
        raise ValueError(f"`stride` must be a whole number of samples, got {stride!r}")
    window, stride = int(window), int(stride)
    if window < 1 or window > T:
        raise ValueError(f"`window` must be between 1 and the signal length {T}, got {window}")
    if stride < 1:
        raise ValueError(f"`stride` must be at least 1, got {stride}")
    return window, stride, (T - window) // stride + 1


def window_starts(T: int, window: int, *, stride: int = 1) -> Int[Array, " windows"]:
    """The first sample index of each window, as used by every function in this module.

    **Arguments:** `T` samples, `window` samples per window, windows starting every `stride`.

    **Returns:** (n_windows,) indices 0, stride, 2·stride, ... with start + window <= T.
    """
    window, stride, nw = _window_args(T, window, stride)
    return jnp.arange(nw) * stride


def windowed_gram(H: Regressor, window: int, *, stride: int = 1) -> Float[Array, "windows n n"]:
    """The windowed Gram matrices (1/T0)∫_{t0}^{t0+T0} H Hᵀ dt of Definition 1.

    Computed from one cumulative sum of the outer products, so the cost is O(T n²) whatever the
    window length. The cumulative sum is taken in the regressor's dtype; in float32 over very long
    records the differences lose digits, so use float64 there.

    **Arguments:**

    - `H`: the regressor (T, n), e.g. `PIOperator.regressor(u)`.
    - `window`: samples per window (T0 / dt).
    - `stride`: samples between window starts.

    **Returns:** (n_windows, n, n), the mean of h_k h_kᵀ over each window.
    """
    H = _regressor(H)
    window, stride, _ = _window_args(H.shape[0], window, stride)
    return _gram(H, window, stride)


# The cores are compiled once per shape, window and stride (the public functions validate first).
@eqx.filter_jit
def _gram(H: Regressor, window: int, stride: int) -> Float[Array, "windows n n"]:
    T, n = H.shape
    window, stride, nw = _window_args(T, window, stride)
    outer = H[:, :, None] * H[:, None, :]
    csum = jnp.concatenate([jnp.zeros((1, n, n), H.dtype), jnp.cumsum(outer, axis=0)])
    starts = jnp.arange(nw) * stride
    gram = (csum[starts + window] - csum[starts]) / window
    return 0.5 * (gram + jnp.swapaxes(gram, -1, -2))


def windowed_pe_levels(H: Regressor, window: int, *, stride: int = 1) -> Float[Array, " windows"]:
    """The smallest eigenvalue of each window's Gram matrix.

    **Arguments:** as [`windowed_gram`][].

    **Returns:** (n_windows,); a window whose value is (numerically) zero is not exciting.
    """
    H = _regressor(H)
    window, stride, _ = _window_args(H.shape[0], window, stride)
    return _pe_levels(H, window, stride)


@eqx.filter_jit
def _pe_levels(H: Regressor, window: int, stride: int) -> Float[Array, " windows"]:
    return jnp.linalg.eigvalsh(_gram(H, window, stride))[:, 0]


def pe_level(H: Regressor, window: int, *, stride: int = 1) -> Scalar:
    """The PE level c1 of Definition 1: the smallest Gram eigenvalue over all windows.

    H is persistently exciting with (T0, c1) when this is positive (and not at rounding level,
    about n·eps·max|h|²).

    **Arguments:** as [`windowed_gram`][].

    **Returns:** c1, a scalar.
    """
    return jnp.min(windowed_pe_levels(H, window, stride=stride))


def _sliding(x: Array, window: int, op) -> Array:
    """op-reduction of x over every run of `window` consecutive samples, by a sparse table.

    Level k holds op over 2**k samples; two overlapping blocks of the largest power of two not
    above `window` cover any window. O(T log window) work, no Python loop over samples.
    """
    table = x
    k = 0
    while (2 ** (k + 1)) <= window:
        span = 2**k
        table = op(table[:-span], table[span:])
        k += 1
    span = 2**k
    n_out = x.shape[0] - window + 1
    return op(table[:n_out], table[window - span : window - span + n_out])


def windowed_range(u, window: int, *, stride: int = 1) -> Float[Array, "windows ..."]:
    """max − min of a signal (T,) or of each column of (T, n) over each window.

    **Arguments:** `u` (T,) or (T, n); `window`, `stride` as in [`windowed_gram`][].

    **Returns:** (n_windows,) or (n_windows, n).
    """
    u = _checks.as_float_array(u, "u")
    if u.ndim not in (1, 2):
        raise ValueError(f"`u` must have shape (T,) or (T, n), got {u.shape}")
    u = _checks.finite(u, "u")
    window, stride, _ = _window_args(u.shape[0], window, stride)
    return _range(u, window, stride)


@eqx.filter_jit
def _range(u: Array, window: int, stride: int) -> Array:
    window, stride, nw = _window_args(u.shape[0], window, stride)
    hi = _sliding(u, window, jnp.maximum)
    lo = _sliding(u, window, jnp.minimum)
    return (hi - lo)[::stride][:nw]


def assumption1_ratio(u: SignalLike, r_max, window: int, *, stride: int = 1) -> Scalar:
    """ρ(T0) = min over windows of (max u − min u) / (2 r_max), paper Assumption 1.

    Assumption 1 holds for this window length when ρ >= 1: every window carries each play through
    both its envelopes, and Theorem 1 then gives persistent excitation.

    **Arguments:**

    - `u`: the input (T,).
    - `r_max`: the largest threshold, positive.
    - `window`, `stride`: as in [`windowed_gram`][].

    **Returns:** ρ, a scalar.
    """
    u = _checks.signal(u)
    r_max = _checks.as_float_array(r_max, "r_max")
    if r_max.ndim != 0:
        raise ValueError(f"`r_max` must be a scalar, got shape {r_max.shape}")
    if _checks.is_concrete(r_max) and not float(r_max) > 0:
        raise ValueError(f"`r_max` must be positive, got {float(r_max)}")
    return jnp.min(windowed_range(u, window, stride=stride)) / (2 * r_max)


def excited_plays(H: Regressor, window: int, *, stride: int = 1, atol: float = 0.0) -> Bool[Array, "windows n"]:
    """Which plays move inside each window (their output range exceeds `atol`).

    A play that stays flat over a window is a constant there; with another flat play or with r_1 = 0
    absent, the plays can be linearly dependent on that window (the failure mode of Lemma 1).

    **Arguments:** `H` (T, n); `window`, `stride` as in [`windowed_gram`][]; `atol` >= 0.

    **Returns:** (n_windows, n) booleans.
    """
    H = _regressor(H)
    return windowed_range(H, window, stride=stride) > atol


class IndependenceCheck(NamedTuple):
    """The result of [`lemma1_check`][].

    **Fields:**

    - `rank`: the numerical rank of the window's regressor.
    - `smallest_singular_value`: its smallest singular value σ_min.
    - `tolerance`: the singular-value threshold below which a direction counts as missing.
    - `independent`: whether `rank == n`, i.e. the play outputs are linearly independent.
    """

    rank: Int[Array, ""]
    smallest_singular_value: Scalar
    tolerance: Scalar
    independent: Bool[Array, ""]


def lemma1_check(H: Regressor, *, rtol: float | None = None) -> IndependenceCheck:
    """Numerical check of Lemma 1: are the play outputs on this window linearly independent?

    The columns of H (the samples of one window) are independent exactly when the window's Gram
    matrix HᵀH/T is positive definite; its smallest eigenvalue is σ_min² / T. Rank is counted with
    singular values above `rtol · σ_max`.

    **Arguments:**

    - `H`: the regressor restricted to the window, (T0/dt, n).
    - `rtol`: relative tolerance; default max(T, n) · eps of the dtype (NumPy's `matrix_rank` rule).

    **Returns:** an `IndependenceCheck(rank, smallest_singular_value, tolerance, independent)`;
    `independent` is `rank == n`.
    """
    H = _regressor(H)
    T, n = H.shape
    if rtol is None:
        rtol = max(T, n) * float(jnp.finfo(H.dtype).eps)
    if not rtol >= 0:
        raise ValueError(f"`rtol` must be non-negative, got {rtol}")
    s = jnp.linalg.svd(H, compute_uv=False)
    smallest = s[n - 1] if T >= n else jnp.zeros((), H.dtype)
    tol = rtol * s[0]
    rank = jnp.sum(s > tol)
    return IndependenceCheck(rank, smallest, tol, rank == n)
