"""Per-window statistics of a play bank, and the sharper excitation condition built on them.

Every windowed quantity comes from per-block values over blocks of g = gcd(window, stride)
samples: a window is k = window / g consecutive blocks and windows start every q = stride / g
blocks, so one pass over the samples plus a small reduction over blocks gives all windows, at
O(T n²) per signal whatever the window.
"""

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from .. import _checks
from .map_settings import numerical_tolerance

SHARPER_STATEMENT = (
    "in every window, n <= min(K, J) + 1, no frozen play sits at 0, and no three plays are "
    "pairwise twins, where K is the number of distinct non-constant play shapes (outputs equal "
    "up to a constant count once), J the number of samples at which some play moves, and two "
    "plays are twins when |h_i - h_j| is constant on the window"
)


def _windows(x, k: int, q: int, op, init):
    """op-reduction of per-block values x (nb, ...) over k consecutive blocks, every q blocks."""
    dims = (k,) + (1,) * (x.ndim - 1)
    strides = (q,) + (1,) * (x.ndim - 1)
    return lax.reduce_window(x, jnp.asarray(init, x.dtype), op, dims, strides, "VALID")


class WindowStats(NamedTuple):
    """What [`window_stats`][] returns, one row per window.

    **Fields:** `gram` (windows, n, n) the mean of h hᵀ; `urange` (windows,) max u − min u;
    `moving` (windows, n) whether each play's output changes inside the window; `shapes`
    (windows,) the number of distinct non-constant shapes among the plays; `zero_frozen`
    (windows,) some play is frozen at 0; `steps` (windows,) the samples inside the window at
    which some play moves; `twin_triple` (windows,) three plays whose pairwise |h_i − h_j| are
    constant.
    """

    gram: jax.Array
    urange: jax.Array
    moving: jax.Array
    shapes: jax.Array
    zero_frozen: jax.Array
    steps: jax.Array
    twin_triple: jax.Array


def window_stats(H, u, window: int, stride: int, rtol, atol) -> WindowStats:
    """Window Grams, input ranges and the play shapes of one play bank (unbatched).

    Shapes come from the increments d_k = h_k − h_{k−1} inside each window: play i is frozen when
    Σ d_i² is 0 (at the relative resolution `rtol` of the largest), and plays i, j have the same
    shape up to a constant when Σ (d_i − d_j)² = D_ii + D_jj − 2 D_ij is 0 (relative to
    D_ii + D_jj), with D the windowed Gram of the increments. Plays i, j are twins when
    |h_i − h_j| does not change inside the window: its windowed max equals its min within
    `atol`. J counts the samples after the window's first at which some play moves.

    **Arguments:** `H` (T, n) the play outputs; `u` (T,) the input; `window`, `stride` in
    samples (static); `rtol` the relative size below which a sum of squared increments counts
    as 0; `atol` how close to 0 a frozen value counts as 0, and how much |h_i − h_j| may vary
    between twins.

    **Returns:** a [`WindowStats`][].
    """
    T, n = H.shape
    g = math.gcd(window, stride)
    nb = T // g
    k, q = window // g, stride // g
    D = jnp.concatenate([jnp.zeros_like(H[:1]), H[1:] - H[:-1]])
    Hb = H[: nb * g].reshape(nb, g, n)
    Db = D[: nb * g].reshape(nb, g, n)
    ub = u[: nb * g].reshape(nb, g)
    mb = jnp.sum(jnp.any(Db != 0, axis=-1), axis=1)
    gram = _windows(jnp.einsum("bgi,bgj->bij", Hb, Hb), k, q, lax.add, 0.0) / window
    dgram = _windows(jnp.einsum("bgi,bgj->bij", Db, Db), k, q, lax.add, 0.0)
    starts = np.arange(gram.shape[0]) * stride
    # The first increment of a window reaches back before it; take it out again.
    d0 = D[starts]
    dgram = dgram - d0[:, :, None] * d0[:, None, :]
    steps = _windows(mb, k, q, lax.add, 0) - jnp.any(d0 != 0, axis=-1)
    urange = _windows(jnp.max(ub, axis=1), k, q, lax.max, -jnp.inf) - _windows(
        jnp.min(ub, axis=1), k, q, lax.min, jnp.inf
    )
    power = jnp.diagonal(dgram, axis1=-2, axis2=-1)
    moving = power > rtol * jnp.max(power, axis=-1, keepdims=True)
    pair = power[:, :, None] + power[:, None, :]
    same = (pair - 2 * dgram <= rtol * pair) & moving[:, :, None] & moving[:, None, :]
    earlier = jnp.tril(jnp.ones((n, n), bool), k=-1)
    shapes = jnp.sum(moving & ~jnp.any(same & earlier, axis=-1), axis=-1)
    zero = jnp.any(~moving & (jnp.abs(H[starts]) <= atol), axis=-1)
    # |h_i − h_j| for every pair i < j, one play i at a time: contiguous slices, no gather.
    hi, lo = [], []
    for i in range(n - 1):
        gap = jnp.abs(Hb[..., i : i + 1] - Hb[..., i + 1 :])
        hi.append(jnp.max(gap, axis=1))
        lo.append(jnp.min(gap, axis=1))
    spread = _windows(jnp.concatenate(hi, axis=-1), k, q, lax.max, -jnp.inf) - _windows(
        jnp.concatenate(lo, axis=-1), k, q, lax.min, jnp.inf
    )
    iu, ju = np.triu_indices(n, 1)  # the same pair order as the loop above
    twin = jnp.zeros(gram.shape, H.dtype).at[:, iu, ju].set((spread <= atol).astype(H.dtype))
    twin = twin + jnp.swapaxes(twin, -1, -2)
    # A triangle in the twin graph: i, j twins and some l twin of both.
    triple = jnp.any((twin > 0) & (twin @ twin > 0), axis=(-1, -2))
    gram = 0.5 * (gram + jnp.swapaxes(gram, -1, -2))
    return WindowStats(gram, urange, moving, shapes, zero, steps, triple)


def holds(stats: WindowStats, n: int):
    """Per window: whether the sharper condition holds (see [`sharper_condition`][])."""
    fits = n - jnp.minimum(stats.shapes, stats.steps) <= 1
    return fits & ~stats.zero_frozen & ~stats.twin_triple


def default_atol(u, r):
    """16 eps (max|u| + max r): how close to 0 a frozen value counts as 0."""
    scale = jnp.max(jnp.abs(u)) + jnp.max(r)
    return 16 * jnp.finfo(u.dtype).eps * scale


def sharper_condition(H, u, window: int, *, stride: int = 1, rtol=None, atol=None):
    """The sharper excitation condition, window by window.

    In a window, two plays have the *same shape* when their outputs differ by a constant there
    (two plays riding the same envelope, or both frozen since the same reversal); a *frozen* play
    is constant. With K distinct non-constant shapes f_1..f_K, every play output lies in
    span{1, f_1, ..., f_K}, of dimension at most K + 1. On sampled data the shapes are also
    spanned by the J samples at which the plays move (each such sample adds one increment), so
    the dimension is at most min(K, J) + 1. Two plays are *twins* when |h_i − h_j| is constant on
    the window (they sit on the same envelope, or are frozen since the same reversal). Three
    pairwise twins are linearly dependent: with nonzero constant gaps |h_j − h_i| = a,
    |h_l − h_i| = b, |h_l − h_j| = c, the signs of h_j − h_i and h_l − h_i can only differ
    where c = a + b and agree only where c = |a − b|, so one of the two never happens and all
    three outputs lie in span{h_i, s} for one sign pattern s(t) (a zero gap is two equal
    plays). This happens to plays whose thresholds are closer than the input moves in one
    sample, which switch envelopes at the same sample. The n plays can only be linearly
    independent on the window when

        n <= min(K, J) + 1,   no frozen play sits at 0,   and no three plays are pairwise twins.

    (Two frozen plays, three plays on one envelope, two pairs sharing shapes, or three plays with
    thresholds unresolved by the sampling all break it.) Failing it is proof of a singular
    window. That it is also enough for a positive PE level is what the Monte Carlo map
    observes, not a theorem.

    **Arguments:** `H` (T, n) play outputs; `u` (T,) the input; `window`, `stride` as in
    `windowed_gram`; `rtol`, the relative size below which a sum of squared increments counts as
    0 (default `numerical_tolerance(dtype)`); `atol`, how close to 0 a frozen value counts as 0,
    and how much |h_i − h_j| may vary between twins (default 16 eps (max|u| + max|H|)).

    **Returns:** (n_windows,) booleans, True where the condition holds.
    """
    H = jnp.asarray(H)
    u = jnp.asarray(u, H.dtype)
    if H.ndim != 2 or u.shape != (H.shape[0],):
        raise ValueError(f"`H` must be (T, n) and `u` (T,), got {H.shape} and {u.shape}")
    if not _checks.is_whole(window) or not 1 <= window <= H.shape[0]:
        raise ValueError(f"`window` must be between 1 and the signal length {H.shape[0]}")
    if not _checks.is_whole(stride) or stride < 1:
        raise ValueError(f"`stride` must be a whole number >= 1, got {stride!r}")
    window, stride = int(window), int(stride)
    rtol = numerical_tolerance(H.dtype) if rtol is None else rtol
    atol = default_atol(u, jnp.max(jnp.abs(H))) if atol is None else atol
    return holds(window_stats(H, u, window, stride, rtol, atol), H.shape[1])
