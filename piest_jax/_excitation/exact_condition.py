"""The exact excitation condition of a window, and a lower bound on its PE level.

See `docs/excitation_condition.md` for the statements and proofs. In short, on a window of samples
a, ..., a + L − 1, every play that moves at a sample k moves the way the input does, by at most
|Δu_k|, and by exactly Δu_k when it was already on that envelope at k − 1 ("continues"). So the
*event row* ρ_k = Δh_k / Δu_k has entries 1 (continuing), in (0, 1) (starting to move) or 0 (still),
and

    rank H_W = rank [h_a; ρ_{a+1}; ...; ρ_{a+L−1}]                          (Theorem 2)

because the rows of H_W are the cumulative sums of h_a and the increments Δh_k = Δu_k ρ_k. The
event matrix's 0/1 entries are decided by comparisons, not by arithmetic, so they are exact; its
scale does not depend on how fast the input moves. Its rank is the exact condition.

The same factorisation H_W = C D (C the cumulative-sum matrix, ‖C⁻¹‖ < 2) bounds the PE level
from below by λ_min(DᵀD) / (4 L) for the increments D between any chosen samples (Theorem 4).
"""

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jaxtyping import Array, Bool, Float

from .. import _checks
from .map_settings import numerical_tolerance
from .pe import _window_args


def _tolerance(tol, dtype):
    if tol is None:
        return jnp.asarray(numerical_tolerance(dtype), dtype)
    if isinstance(tol, bool) or not isinstance(tol, int | float) or not 0 <= tol < 1:
        raise ValueError(f"`tol` must be a number in [0, 1) (a level λ_min / λ_max), got {tol!r}")
    return jnp.asarray(tol, dtype)


def _like(x, dtype):
    """`x` as a JAX array of `dtype`: concrete values through the host (`_checks.to_device`),
    which compiles nothing, where `jnp.asarray` compiles a conversion for every new shape."""
    if isinstance(x, jax.Array) and x.dtype == dtype:
        return x
    if all(_checks.is_concrete(leaf) for leaf in jax.tree.leaves(x)):  # a list may hold tracers
        return _checks.to_device(np.asarray(x, dtype))
    return jnp.asarray(x, dtype)


def _inputs(H, u, r, window, stride):
    H = _checks.as_float_array(H, "H")
    if H.ndim != 2:
        raise ValueError(f"`H` must be the play outputs (T, n), got shape {H.shape}")
    u, r = _like(u, H.dtype), _like(r, H.dtype)
    if u.shape != (H.shape[0],):
        raise ValueError(f"`u` must have shape ({H.shape[0]},) like H's rows, got {u.shape}")
    if r.shape != (H.shape[1],):
        raise ValueError(f"`r` must have shape ({H.shape[1]},), one threshold per play, got {r.shape}")
    _window_args(H.shape[0], window, stride)
    return _checks.finite(H, "H"), _checks.finite(u, "u"), _checks.thresholds(r, "r")


@eqx.filter_jit
def _event_rows(H, u, r):
    # The play step is max(u − r, min(u + r, x)): the output sits on an envelope exactly when it
    # equals the very float that step computed, so these equalities are exact, not tolerances.
    prev = jnp.concatenate([H[:1], H[:-1]])
    up = jnp.concatenate([jnp.zeros_like(H[:1], bool), H[:-1] == (u[:-1, None] - r)])
    down = jnp.concatenate([jnp.zeros_like(H[:1], bool), H[:-1] == (u[:-1, None] + r)])
    du = jnp.concatenate([jnp.zeros((1,), u.dtype), u[1:] - u[:-1]])
    moving = H != prev
    continuing = moving & jnp.where(du[:, None] > 0, up, down)
    safe = jnp.where(du == 0, jnp.ones_like(du), du)
    # A continuing play moves by exactly Δu: its entry is 1 by Lemma 1, not a rounded quotient.
    rho = jnp.where(continuing, 1.0, jnp.where(moving, (H - prev) / safe[:, None], 0.0))
    return rho.astype(H.dtype), moving, continuing


class EventRows(NamedTuple):
    """What [`event_rows`][] returns, one row per sample (row 0 is all zero: no increment).

    **Fields:** `rho` (T, n) the event rows Δh_k / Δu_k, entries in [0, 1]; `moving` (T, n)
    whether each play's output changes at sample k; `continuing` (T, n) whether it moves by
    exactly Δu_k (it was on that envelope at k − 1).
    """

    rho: Float[Array, "T n"]
    moving: Bool[Array, "T n"]
    continuing: Bool[Array, "T n"]


def event_rows(H, u, r) -> EventRows:
    """The event rows ρ_k = Δh_k / Δu_k of a play bank (Lemma 1 of `docs/excitation_condition.md`).

    **Arguments:** `H` (T, n) the play outputs of the input `u` (T,) with thresholds `r` (n,),
    as computed by `piest_jax.play` (the envelope tests compare with the floats it computes).

    **Returns:** an [`EventRows`][].
    """
    H, u, r = _inputs(H, u, r, 1, 1)
    return EventRows(*_event_rows(H, u, r))


class ExactCondition(NamedTuple):
    """What [`exact_condition`][] returns, one entry per window.

    **Fields:** `holds` (windows,) whether the event matrix has full rank n (the window is PE);
    `level` (windows,) the event matrix's λ_min / λ_max, scale free, compared with `tolerance`;
    `tolerance` the level below which the rank counts as deficient.
    """

    holds: Bool[Array, " windows"]
    level: Float[Array, " windows"]
    tolerance: Float[Array, ""]


@eqx.filter_jit
def _event_level(H, u, r, window: int, stride: int):
    T, n = H.shape
    window, stride, nw = _window_args(T, window, stride)
    rho, _, _ = _event_rows(H, u, r)
    outer = rho[:, :, None] * rho[:, None, :]
    csum = jnp.concatenate([jnp.zeros((1, n, n), H.dtype), jnp.cumsum(outer, axis=0)])
    starts = jnp.arange(nw) * stride
    # Increments strictly inside the window: samples a + 1, ..., a + L − 1.
    gram = csum[starts + window] - csum[starts + 1]
    h0 = H[starts]
    scale = jnp.max(jnp.abs(h0), axis=-1, keepdims=True)
    h0 = h0 / jnp.where(scale > 0, scale, 1.0)
    gram = gram + h0[:, :, None] * h0[:, None, :]
    gram = 0.5 * (gram + jnp.swapaxes(gram, -1, -2))
    lam = lax.map(jnp.linalg.eigvalsh, gram)
    return lam[:, 0] / jnp.maximum(lam[:, -1], jnp.finfo(H.dtype).tiny)


def exact_condition(H, u, r, window: int, *, stride: int = 1, tol=None) -> ExactCondition:
    """The exact excitation condition (Theorem 2 of `docs/excitation_condition.md`), per window.

    A window of samples a, ..., a + L − 1 is PE (its Gram matrix of H is positive definite)
    exactly when the event matrix [h_a; ρ_{a+1}; ...; ρ_{a+L−1}] has rank n. Its rank is read
    from the eigenvalues of the sum of the rows' outer products (h_a scaled to max |h_a| = 1);
    entries of ρ are 0 or 1 by exact comparisons and fractions only where a play starts to move,
    so the level does not shrink with the sampling step as the raw Gram's does.

    **Arguments:**

    - `H`: the play outputs (T, n) of `u` with thresholds `r`, from `piest_jax.play`.
    - `u`: the input (T,).
    - `r`: the thresholds (n,), >= 0.
    - `window`, `stride`: as in `windowed_gram`.
    - `tol`: the level λ_min / λ_max of the event matrix below which its rank counts as
      deficient; default `numerical_tolerance(dtype)` (2.2e-12 in float64).

    **Returns:** an [`ExactCondition`][] `(holds, level, tolerance)`.
    """
    H, u, r = _inputs(H, u, r, window, stride)
    window, stride = int(window), int(stride)  # NumPy integers too, static under jit
    tol = _tolerance(tol, H.dtype)
    holds, level = _holds(H, u, r, tol, window, stride)
    return ExactCondition(holds, level, tol)


# The comparisons after the compiled level and margin are compiled with them: run one by one they
# would each compile a program of their own for every new shape.
@eqx.filter_jit
def _holds(H, u, r, tol, window: int, stride: int):
    level = _event_level(H, u, r, window, stride)
    return level > tol, level


@eqx.filter_jit
def _bounded_margin(H, u, r, tol, window: int, stride: int):
    ok = _event_level(H, u, r, window, stride) > tol
    return jnp.where(ok, _margin(H, u, r, window, stride), 0.0)


def _segment_ends(rho, du, moving):
    """Samples after which the event row changes: where one segment of equal rows ends."""
    key_same = jnp.all(rho[1:] == rho[:-1], axis=-1) & (jnp.sign(du[1:]) == jnp.sign(du[:-1]))
    # Sample k ends a segment when row k + 1 differs from row k or k + 1 moves nothing.
    ends = ~key_same | ~jnp.any(moving[1:], axis=-1)
    return jnp.concatenate([ends, jnp.ones((1,), bool)])


@eqx.filter_jit
def _margin(H, u, r, window: int, stride: int):
    T, n = H.shape
    window, stride, nw = _window_args(T, window, stride)
    rho, moving, _ = _event_rows(H, u, r)
    du = jnp.concatenate([jnp.zeros((1,), u.dtype), u[1:] - u[:-1]])
    ends = _segment_ends(rho, du, moving)
    idx = jnp.arange(window)

    def one(a):
        Hw = lax.dynamic_slice_in_dim(H, a, window)
        keep = lax.dynamic_slice_in_dim(ends, a, window)
        # The window's first and last samples are always kept; any other choice of kept samples
        # gives a valid bound (Theorem 4), the segment ends only make it tighter.
        keep = keep.at[0].set(True).at[-1].set(True)
        last = lax.cummax(jnp.where(keep, idx, -1))
        prev = jnp.concatenate([jnp.full((1,), -1), last[:-1]])
        base = jnp.where(prev[:, None] >= 0, Hw[jnp.maximum(prev, 0)], 0.0)
        D = jnp.where(keep[:, None], Hw - base, 0.0)
        lam = jnp.linalg.eigvalsh(D.T @ D)
        return jnp.maximum(lam[0], 0.0) / (4 * window)

    return lax.map(one, jnp.arange(nw) * stride)


def pe_margin(H, u, r, window: int, *, stride: int = 1, tol=None) -> Float[Array, " windows"]:
    """A lower bound on each window's PE level λ_min((1/L) Σ h hᵀ) (Theorem 4).

    With the samples a = k_0 < k_1 < ... < k_m = a + L − 1 where the event row changes (the
    segment ends: reversals, plays starting or stopping), and D the rows h_{k_0}, h_{k_1} − h_{k_0},
    ..., the window's rows include C D with C the lower-triangular ones matrix, whose inverse has
    norm < 2, so λ_min(H_Wᵀ H_W) >= λ_min(DᵀD) / 4. The bound is read from the input's swings
    between events (Δu summed over each segment), not from the sampling rate. Windows where the
    exact condition fails get 0.

    **Arguments:** as [`exact_condition`][].

    **Returns:** (n_windows,) lower bounds, each <= the window's value of `windowed_pe_levels`
    (up to rounding, about n eps times the Gram's largest eigenvalue).
    """
    H, u, r = _inputs(H, u, r, window, stride)
    window, stride = int(window), int(stride)  # NumPy integers too, static under jit
    tol = _tolerance(tol, H.dtype)
    return _bounded_margin(H, u, r, tol, window, stride)
