"""Every per-draw quantity of the Monte Carlo PE map, for one case (unbatched).

For one input u, threshold set r, initial states x0 and true weights w, over windows of `window`
samples starting every `stride` samples:

- ρ, the Assumption 1 ratio: the smallest window range of u divided by 2 r_max;
- c1, the PE level: the smallest eigenvalue over windows of the mean of h hᵀ (Definition 1), and
  its normalised form, the smallest over windows of λ_min / λ_max (scale free: 0 for a singular
  window, 1 for a perfectly conditioned one);
- which plays move in each window, and whether every window satisfies the sharper condition;
- the relative weight error ‖Ŵ − W‖/‖W‖ of the paper's continuous RLS (`ContinuousRLS`, P0·I,
  Ŵ0 = 0) after `rls_samples` samples of noise-free data, from its exact information form
  W̃ = −(I + P0 A)⁻¹ W, A = Σ c_k h_k h_kᵀ, c_k = dt/(1 + h_kᵀh_k)²;
- the time that error takes to fall below 1 % for good, measured every `stride` samples, and
  the time the margin guarantees it by (`guaranteed_samples`).
"""

import math

import jax.numpy as jnp
from jax import lax

from .._operators.play import _bank
from .condition import default_atol, holds, window_stats
from .exact_condition import _event_level, _margin
from .map_settings import MapSettings, numerical_tolerance

#: The relative weight error whose first passage the map times.
TARGET_ERROR = 0.01


def _checkpoints(n_samples: int, stride: int):
    """Samples after which the weight error is read: every `stride`, and the last."""
    return jnp.minimum(jnp.arange(1, -(-n_samples // stride) + 1) * stride, n_samples)


def _first_for_good(below, checkpoints):
    """The first checkpoint from which `below` holds at every later one; −1 if the last fails."""
    stays = lax.cummin(below.astype(jnp.int32), reverse=True).astype(bool)
    first = jnp.argmax(stays)
    return jnp.where(stays[-1], checkpoints[first], -1)


def cumulative_information(H, dt: float, n_samples: int, block: int):
    """The RLS information A_k = Σ_{i<k} c_i h_i h_iᵀ, c_i = dt / (1 + h_iᵀ h_i)², read every
    `block` samples up to `n_samples` (the paper's normalisation m = 1 + hᵀh, divided by m²).

    **Returns:** `(k, A)`: sample counts (K,) = block, 2 block, ..., n_samples, and A_k (K, n, n).
    """
    n = H.shape[1]
    k = _checkpoints(n_samples, block)
    Hr = jnp.zeros((k.shape[0] * block, n), H.dtype).at[:n_samples].set(H[:n_samples])
    c = dt / (1 + jnp.sum(Hr * Hr, axis=1)) ** 2
    blocks = jnp.einsum("bki,bkj->bij", *(x.reshape(-1, block, n) for x in (Hr * c[:, None], Hr)))
    return k, jnp.cumsum(blocks, axis=0)


def samples_to_target(H, w, settings: MapSettings):
    """When the RLS weight error falls below `TARGET_ERROR` for good (checked every `stride`).

    The error after k samples is ‖(I + P0 A_k)⁻¹ W‖ / ‖W‖ with A_k from
    `cumulative_information` (the information form of `draw_statistics`), read at
    k = stride, 2 stride, ..., `rls_samples`; its worst case over weight vectors W is
    1 / (1 + P0 λ_min(A_k)), which depends on the input only.

    **Returns:** `(measured, worst, error, worst_error)`: the first k from which every later
    reading of the error for `w` (of its worst case) is below the target, or −1; both errors
    after `rls_samples`.
    """
    s = settings
    checks, A = cumulative_information(H, s.dt, s.rls_samples, s.stride)

    def errors(A):
        # One matrix per call (see the eigensolver note in `draw_statistics`).
        lam, V = jnp.linalg.eigh(0.5 * (A + A.T))
        shrink = 1 / (1 + s.P0 * jnp.maximum(lam, 0.0))
        return jnp.linalg.norm(V @ ((V.T @ w) * shrink)), shrink[0]

    err, worst = lax.map(errors, A)
    err = err / jnp.linalg.norm(w)
    return (
        _first_for_good(err <= TARGET_ERROR, checks),
        _first_for_good(worst <= TARGET_ERROR, checks),
        err[-1],
        worst[-1],
    )


def guaranteed_samples(H, margins, settings: MapSettings):
    """The sample count after which the margins guarantee an RLS weight error below 1 %.

    On disjoint windows W_j (length L, starting every `stride`·⌈L/stride⌉ samples, so each is one
    of the map's windows), Σ_{i∈W_j} c_i h_i h_iᵀ ⪰ L · min_{i∈W_j} c_i · margin_j · I, so after
    the first m windows the error ‖(I + P0 A)⁻¹ W‖/‖W‖ is at most 1/(1 + P0 L Σ_{j<m} c_j margin_j),
    and it only falls from there (A only grows). The guarantee is that bound reaching 1 %,
    rounded up to the next reading of `samples_to_target` (so measured <= guaranteed).

    **Arguments:** `H` (T, n) the play outputs; `margins` (n_windows,) from `pe_margin`'s core.

    **Returns:** `(samples, bound)`: the guaranteed sample count, or −1 when the bound does not
    reach 1 % within `rls_samples`; the bound on the relative error after `rls_samples` (1 when
    no whole window fits).
    """
    s = settings
    step = math.ceil(s.window / s.stride)
    n_disjoint = max(0, (s.rls_samples - s.window) // (step * s.stride) + 1)
    if n_disjoint == 0:
        return jnp.asarray(-1), jnp.asarray(1.0, H.dtype)
    starts = jnp.arange(n_disjoint) * step * s.stride
    sq = jnp.sum(H * H, axis=1)
    peak = lax.map(lambda a: jnp.max(lax.dynamic_slice_in_dim(sq, a, s.window)), starts)
    gain = s.P0 * s.window * s.dt / (1 + peak) ** 2 * margins[::step][:n_disjoint]
    total = 1 + jnp.cumsum(gain)
    reached = total >= 1 / TARGET_ERROR
    end = starts + s.window
    rounded = jnp.minimum(-(-end // s.stride) * s.stride, s.rls_samples)
    return jnp.where(jnp.any(reached), rounded[jnp.argmax(reached)], -1), 1 / total[-1]


def draw_statistics(u, r, x0, w, settings: MapSettings) -> dict:
    """Every per-draw quantity of the map for one case (unbatched: batch with `jax.vmap`).

    **Arguments:** the input `u` (T,), thresholds `r` (n,, increasing), initial states `x0` (n,),
    true weights `w` (n,) (as from `draw_case`); `settings` from [`make_settings`][].

    **Returns:** a dict of arrays: `rho`, `c1`, `c1_normalised`, `gram_scale` (the largest
    λ_max over windows: c1 is only known to a few eps times it), `excited` (n_windows, n)
    booleans, `min_excited` (fewest plays moving in any window), `redundant` (the largest
    n − min(K, J) over windows: K distinct moving shapes, J samples with movement),
    `zero_frozen` (some window has a play frozen at 0), `twin_triple` (some window has three
    pairwise twin plays), `sharper` (the sharper condition in every window), `exact` (the exact
    condition, `exact_condition`, in every window), `exact_level` (the smallest event-matrix
    level λ_min / λ_max over windows), `margin` (the smallest `pe_margin` over windows: a lower
    bound on c1), `weight_error`, `samples_to_1pct` (when that error falls below 1 % for good,
    read every `stride` samples; −1: not within `rls_samples`) and `guaranteed_samples_to_1pct`
    (when the margins guarantee it, `guaranteed_samples`; −1: they do not within the record),
    `worst_samples_to_1pct` (the same for the worst weight vector, which the guarantee bounds),
    `worst_error` (that worst case after `rls_samples`: 1 / (1 + P0 λ_min(A))) and
    `guaranteed_error` (the margins' bound on it).
    """
    s = settings
    dtype = u.dtype
    # The drawn cases are valid by construction, so the play bank is called without the input
    # checks of `play` (their runtime error branches do not mix with shard_map), nor the kernel's
    # check of u, which would keep the map's program out of the persistent compilation cache.
    H = _bank(u, r, x0, s.play_method, check_finite=False)
    stats = window_stats(H, u, s.window, s.stride, numerical_tolerance(dtype), default_atol(u, r))
    level = _event_level(H, u, r, s.window, s.stride)
    exact = level > numerical_tolerance(dtype)
    margins = jnp.where(exact, _margin(H, u, r, s.window, s.stride), 0.0)
    # One matrix per eigensolver call, in a loop. The batched CPU solver splits a large batch
    # into tasks on XLA:CPU's intra-op pool and blocks a pool thread until they finish; two such
    # calls at once (one per device when a CPU is split into several, or two calls scheduled
    # side by side) can hold every pool thread and wait forever. A single matrix runs inline.
    eig = lax.map(jnp.linalg.eigvalsh, stats.gram)
    lam_min, lam_max = eig[:, 0], eig[:, -1]
    measured, worst, weight_error, worst_error = samples_to_target(H, w, s)
    guaranteed, guaranteed_error = guaranteed_samples(H, margins, s)
    return dict(
        rho=jnp.min(stats.urange) / (2 * r[-1]),
        c1=jnp.min(lam_min),
        c1_normalised=jnp.min(lam_min / jnp.maximum(lam_max, jnp.finfo(dtype).tiny)),
        gram_scale=jnp.max(lam_max),
        excited=stats.moving,
        min_excited=jnp.min(jnp.sum(stats.moving, axis=-1)),
        redundant=jnp.max(r.shape[0] - jnp.minimum(stats.shapes, stats.steps)),
        zero_frozen=jnp.any(stats.zero_frozen),
        twin_triple=jnp.any(stats.twin_triple),
        sharper=jnp.all(holds(stats, r.shape[0])),
        exact=jnp.all(exact),
        exact_level=jnp.min(level),
        margin=jnp.min(margins),
        weight_error=weight_error,
        samples_to_1pct=measured,
        worst_samples_to_1pct=worst,
        guaranteed_samples_to_1pct=guaranteed,
        worst_error=worst_error,
        guaranteed_error=guaranteed_error,
    )
