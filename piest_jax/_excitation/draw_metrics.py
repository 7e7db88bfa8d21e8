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
  W̃ = −(I + P0 A)⁻¹ W, A = Σ c_k h_k h_kᵀ, c_k = dt/(1 + h_kᵀh_k)².
"""

import jax.numpy as jnp
from jax import lax

from .._operators.play import _bank
from .condition import default_atol, holds, window_stats
from .exact_condition import _event_level, _margin
from .map_settings import MapSettings, numerical_tolerance


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
    bound on c1), `weight_error`.
    """
    s = settings
    dtype = u.dtype
    # The drawn cases are valid by construction, so the play bank is called without the input
    # checks of `play` (their runtime error branches do not mix with shard_map).
    H = _bank(u, r, x0, s.play_method)
    stats = window_stats(H, u, s.window, s.stride, numerical_tolerance(dtype), default_atol(u, r))
    level = _event_level(H, u, r, s.window, s.stride)
    exact = level > numerical_tolerance(dtype)
    margin = jnp.where(exact, _margin(H, u, r, s.window, s.stride), 0.0)
    Hr = H[: s.rls_samples]
    c = (s.dt / (1 + jnp.sum(Hr * Hr, axis=1)) ** 2).astype(dtype)
    A = (Hr * c[:, None]).T @ Hr
    # One matrix per eigensolver call, in a loop. The batched CPU solver splits a large batch
    # into tasks on XLA:CPU's intra-op pool and blocks a pool thread until they finish; two such
    # calls at once (one per device when a CPU is split into several, or two calls scheduled
    # side by side) can hold every pool thread and wait forever. A single matrix runs inline.
    lam_all, V_all = lax.map(
        jnp.linalg.eigh, jnp.concatenate([stats.gram, (0.5 * (A + A.T))[None]])
    )
    eig, lam, V = lam_all[:-1], lam_all[-1], V_all[-1]
    lam_min, lam_max = eig[:, 0], eig[:, -1]
    err = V @ ((V.T @ w) / (1 + s.P0 * jnp.maximum(lam, 0.0)))
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
        margin=jnp.min(margin),
        weight_error=jnp.linalg.norm(err) / jnp.linalg.norm(w),
    )
