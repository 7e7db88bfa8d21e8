"""Monte Carlo map of persistent excitation against Assumption 1, sharded over devices.

One draw is one PRNG key: it fixes an input family and its parameters, a threshold set, initial
play states and true weights (see `_families.py`). For each draw the engine computes, over windows
of `window` samples starting every `stride` samples,

- ρ, the Assumption 1 ratio: the smallest window range of u divided by 2 r_max;
- c1, the PE level: the smallest eigenvalue over windows of the mean of h hᵀ (Definition 1), and
  its normalised form, the smallest over windows of λ_min / λ_max (scale free: 0 for a singular
  window, 1 for a perfectly conditioned one);
- which plays move in each window, and which windows satisfy the sharper condition (see
  [`sharper_condition`][]);
- the relative weight error ‖Ŵ − W‖/‖W‖ of the paper's continuous RLS (`ContinuousRLS`, P0·I,
  Ŵ0 = 0) after `rls_samples` samples of noise-free data, from its exact information form
  W̃ = −(I + P0 A)⁻¹ W, A = Σ c_k h_k h_kᵀ, c_k = dt/(1 + h_kᵀh_k)².

All windowed quantities come from per-block sums over blocks of g = gcd(window, stride) samples
(one small matrix product per draw, no (T, n, n) array), so the cost is O(T n²) per draw whatever
the window. The batch runs as one jitted computation per chunk of keys, with the key axis sharded
over every JAX device through a one-axis `Mesh` and `NamedSharding`.
"""

import functools
import math
import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from ._families import FAMILIES, draw_case, family_indices
from ._play import METHODS, _bank
from ._progress import progress


class MapSettings(NamedTuple):
    """Static settings of a map (hashable: one compiled engine per distinct value).

    **Fields:** `n_samples` T; `n_plays` n; `window` samples per PE window (T0/dt); `stride`
    samples between window starts; `dt` the sampling step; `P0` the RLS initial gain (P0·I);
    `rls_samples` samples the RLS has seen when its error is read; `families` indices into
    `FAMILIES` to draw from; `dtype` the floating type of the whole computation; `play_method`
    how the play bank is computed (`"scan"`, or `"kernel"` / `"auto"` for the compiled CPU
    kernel, which gives the same outputs to the last bit).
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
    play_method: str = "scan"


def make_settings(
    *,
    n_samples: int,
    n_plays: int = 10,
    window: int | None = None,
    stride: int | None = None,
    dt: float = 2e-3,
    P0: float = 1e6,
    rls_samples: int | None = None,
    families=FAMILIES,
    dtype=None,
    play_method: str = "scan",
) -> MapSettings:
    """Check and complete the settings of a map.

    **Arguments:** `n_samples` >= 2; `n_plays` >= 1; `window` in [1, n_samples] (default
    n_samples // 5); `stride` >= 1 (default window // 10); `dt` > 0; `P0` > 0; `rls_samples` in
    [1, n_samples] (default n_samples); `families`, names from `FAMILIES`; `dtype`, float32 or
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
    if dtype == jnp.dtype("float64") and not jax.config.jax_enable_x64:
        raise ValueError("float64 needs jax_enable_x64; enable it or ask for float32")
    if play_method not in METHODS:
        raise ValueError(f"unknown play method {play_method!r}; choose one of {METHODS}")
    idx = family_indices(families)
    return MapSettings(
        T, n, window, stride, float(dt), float(P0), rls, idx, dtype.name, play_method
    )


def numerical_tolerance(dtype) -> float:
    """The tolerance on the normalised PE level below which a draw counts as not PE.

    λ_min of a window Gram is only known to about (samples summed) · eps · λ_max, so a normalised
    level below 1e4 · eps (2.2e-12 in float64, 1.2e-3 in float32) is rounding, not excitation.
    """
    return 1e4 * float(jnp.finfo(jnp.dtype(dtype)).eps)


def _windows(x, k: int, q: int, op, init):
    """op-reduction of per-block values x (nb, ...) over k consecutive blocks, every q blocks."""
    dims = (k,) + (1,) * (x.ndim - 1)
    strides = (q,) + (1,) * (x.ndim - 1)
    return lax.reduce_window(x, jnp.asarray(init, x.dtype), op, dims, strides, "VALID")


class _WindowStats(NamedTuple):
    gram: jax.Array  # (windows, n, n) mean of h hᵀ
    urange: jax.Array  # (windows,) max u − min u
    moving: jax.Array  # (windows, n) the play's output changes inside the window
    shapes: jax.Array  # (windows,) distinct non-constant shapes among the plays
    zero_frozen: jax.Array  # (windows,) some play is frozen at 0
    steps: jax.Array  # (windows,) samples inside the window at which some play moves
    twin_triple: jax.Array  # (windows,) three plays whose pairwise |h_i − h_j| are constant


def _window_stats(H, u, window: int, stride: int, rtol, atol) -> _WindowStats:
    """Window Grams, input ranges and the play shapes, all from block sums (module docstring).

    Shapes come from the increments d_k = h_k − h_{k−1} inside each window: play i is frozen when
    Σ d_i² is 0, and plays i, j have the same shape up to a constant when Σ (d_i − d_j)² =
    D_ii + D_jj − 2 D_ij is 0, with D the windowed Gram of the increments. Plays i, j are twins
    when |h_i − h_j| does not change inside the window (its windowed max equals its min).
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
    starts = jnp.arange(gram.shape[0]) * stride
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
    iu, ju = np.triu_indices(n, 1)
    gap = jnp.abs(Hb[..., iu] - Hb[..., ju])
    spread = _windows(jnp.max(gap, axis=1), k, q, lax.max, -jnp.inf) - _windows(
        jnp.min(gap, axis=1), k, q, lax.min, jnp.inf
    )
    twin = jnp.zeros(gram.shape, H.dtype).at[:, iu, ju].set((spread <= atol).astype(H.dtype))
    twin = twin + jnp.swapaxes(twin, -1, -2)
    # A triangle in the twin graph: i, j twins and some l twin of both.
    triple = jnp.any((twin > 0) & (twin @ twin > 0), axis=(-1, -2))
    gram = 0.5 * (gram + jnp.swapaxes(gram, -1, -2))
    return _WindowStats(gram, urange, moving, shapes, zero, steps, triple)


def _holds(stats: _WindowStats, n: int):
    """Per window: the sharper condition (see `sharper_condition`)."""
    fits = n - jnp.minimum(stats.shapes, stats.steps) <= 1
    return fits & ~stats.zero_frozen & ~stats.twin_triple


def _atol(u, r):
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
    plays). This happens to plays whose
    thresholds are closer than the input moves in one sample, which switch envelopes at the same
    sample. The n plays can only be linearly independent on the window when

        n <= min(K, J) + 1,   no frozen play sits at 0,   and no three plays are pairwise twins.

    (Two frozen plays, three plays on one envelope, two pairs sharing shapes, or three plays with
    thresholds unresolved by the sampling all break it.) Failing it is proof of a singular
    window. That it is also enough for a positive PE level is what the Monte Carlo map
    observes, not a theorem.

    **Arguments:** `H` (T, n) play outputs; `u` (T,) the input; `window`, `stride` as in
    `windowed_gram`; `rtol`, the relative size below which a sum of squared increments counts as
    0 (default `numerical_tolerance(dtype)`); `atol`, how close to 0 a frozen value counts as 0
    (default 16 eps (max|u| + max|H|)).

    **Returns:** (n_windows,) booleans, True where the condition holds.
    """
    H = jnp.asarray(H)
    u = jnp.asarray(u, H.dtype)
    if H.ndim != 2 or u.shape != (H.shape[0],):
        raise ValueError(f"`H` must be (T, n) and `u` (T,), got {H.shape} and {u.shape}")
    if isinstance(window, bool) or not isinstance(window, int) or not 1 <= window <= H.shape[0]:
        raise ValueError(f"`window` must be between 1 and the signal length {H.shape[0]}")
    if isinstance(stride, bool) or not isinstance(stride, int) or stride < 1:
        raise ValueError(f"`stride` must be a whole number >= 1, got {stride!r}")
    rtol = numerical_tolerance(H.dtype) if rtol is None else rtol
    atol = _atol(u, jnp.max(jnp.abs(H))) if atol is None else atol
    return _holds(_window_stats(H, u, window, stride, rtol, atol), H.shape[1])


def draw_statistics(u, r, x0, w, settings: MapSettings) -> dict:
    """Every per-draw quantity of the map for one case (unbatched; the engine vmaps it).

    **Arguments:** the input `u` (T,), thresholds `r` (n,, increasing), initial states `x0` (n,),
    true weights `w` (n,) (as from `draw_case`); `settings` from [`make_settings`][].

    **Returns:** a dict of arrays: `rho`, `c1`, `c1_normalised`, `excited` (n_windows, n)
    booleans, `min_excited` (fewest plays moving in any window), `redundant` (the largest
    n − min(K, J) over windows: K distinct moving shapes, J samples with movement),
    `zero_frozen` (some window has a play frozen at 0), `twin_triple` (some window has three
    pairwise twin plays), `sharper` (the sharper condition in every window), `weight_error`.
    """
    s = settings
    dtype = u.dtype
    # The drawn cases are valid by construction, so the play bank is called without the input
    # checks of `play` (their runtime error branches do not mix with shard_map).
    H = _bank(u, r, x0, s.play_method)
    stats = _window_stats(H, u, s.window, s.stride, numerical_tolerance(dtype), _atol(u, r))
    Hr = H[: s.rls_samples]
    c = (s.dt / (1 + jnp.sum(Hr * Hr, axis=1)) ** 2).astype(dtype)
    A = (Hr * c[:, None]).T @ Hr
    # One eigensolver call for the window Grams and the RLS information matrix together: the
    # batched solver waits on helpers it queues in XLA:CPU's intra-op pool, so two solver calls
    # scheduled side by side can hold every pool thread and wait forever.
    lam_all, V_all = jnp.linalg.eigh(jnp.concatenate([stats.gram, (0.5 * (A + A.T))[None]]))
    eig, lam, V = lam_all[:-1], lam_all[-1], V_all[-1]
    lam_min, lam_max = eig[:, 0], eig[:, -1]
    err = V @ ((V.T @ w) / (1 + s.P0 * jnp.maximum(lam, 0.0)))
    return dict(
        rho=jnp.min(stats.urange) / (2 * r[-1]),
        c1=jnp.min(lam_min),
        c1_normalised=jnp.min(lam_min / jnp.maximum(lam_max, jnp.finfo(dtype).tiny)),
        excited=stats.moving,
        min_excited=jnp.min(jnp.sum(stats.moving, axis=-1)),
        redundant=jnp.max(r.shape[0] - jnp.minimum(stats.shapes, stats.steps)),
        zero_frozen=jnp.any(stats.zero_frozen),
        twin_triple=jnp.any(stats.twin_triple),
        sharper=jnp.all(_holds(stats, r.shape[0])),
        weight_error=jnp.linalg.norm(err) / jnp.linalg.norm(w),
    )


def draw_keys(key, start: int, count: int):
    """Keys of draws start, ..., start + count − 1: draw i is fold_in(key, i), whatever the batch."""
    return jax.vmap(lambda i: jax.random.fold_in(key, i))(jnp.arange(start, start + count))


def draw_family(index, settings: MapSettings):
    """The family (index into `FAMILIES`) of draw number `index`: the families take turns."""
    return np.asarray(settings.families)[np.asarray(index) % len(settings.families)]


def _local_batch(keys, settings: MapSettings) -> dict:
    """Statistics of a batch of keys whose first draw number is a multiple of the family count."""
    s = settings
    nf = len(s.families)
    t = jnp.arange(s.n_samples, dtype=jnp.dtype(s.dtype)) * jnp.asarray(s.dt, s.dtype)
    by_family = keys.reshape(-1, nf)
    cases = [
        jax.vmap(lambda k, f=f: draw_case(k, f, t, s.n_plays))(by_family[:, j])
        for j, f in enumerate(s.families)
    ]
    # Interleave back so row i of the result is draw i of the batch.
    u, r, x0, w = (jnp.stack(parts, axis=1).reshape((keys.shape[0],) + parts[0].shape[1:])
                   for parts in zip(*cases))
    out = jax.vmap(functools.partial(draw_statistics, settings=s))(u, r, x0, w)
    out["thresholds"] = r
    return out


@functools.lru_cache(maxsize=16)
def _engine(settings: MapSettings, devices: tuple):
    mesh = Mesh(np.asarray(devices), ("batch",))
    spec = PartitionSpec("batch")
    # shard_map keeps every device on its own slice of keys, also through the compiled play
    # kernel, which the automatic partitioner could not split.
    fn = jax.shard_map(
        functools.partial(_local_batch, settings=settings),
        mesh=mesh,
        in_specs=spec,
        out_specs=spec,
    )
    sharding = NamedSharding(mesh, spec)
    return jax.jit(fn, in_shardings=sharding, out_shardings=sharding), sharding


def pe_map(
    key,
    n_draws: int,
    settings: MapSettings,
    *,
    chunk: int = 1000,
    start: int = 0,
    devices=None,
    quiet: bool = False,
) -> dict:
    """Run the Monte Carlo map: `n_draws` draws, `chunk` at a time, sharded over `devices`.

    **Arguments:**

    - `key`: a PRNG key; draw i uses `fold_in(key, i)` and family `draw_family(i)`, so results do
      not depend on `chunk` or on the number of devices.
    - `n_draws`: number of draws, >= 1.
    - `settings`: from [`make_settings`][].
    - `chunk`: draws per jitted call (bounds memory); rounded up to a multiple of the device count
      times the number of families.
    - `start`: the number of the first draw, a multiple of the number of families: a long map
      can be split over runs or hosts (draws start, ..., start + n_draws − 1).
    - `devices`: the devices to shard over (default all of `jax.devices()`).
    - `quiet`: no progress bar.

    **Returns:** a dict of NumPy arrays with a leading axis of `n_draws` (see
    [`draw_statistics`][]), plus `seconds`, the wall time including compilation.
    """
    for name, v in (("n_draws", n_draws), ("chunk", chunk)):
        if isinstance(v, bool) or not isinstance(v, int | np.integer) or v < 1:
            raise ValueError(f"`{name}` must be a positive whole number, got {v!r}")
    if not isinstance(settings, MapSettings):
        raise ValueError("`settings` must come from make_settings(...)")
    nf = len(settings.families)
    if isinstance(start, bool) or not isinstance(start, int | np.integer) or start % nf or start < 0:
        raise ValueError(f"`start` must be a non-negative multiple of {nf} (the families), got {start!r}")
    devices = tuple(jax.devices() if devices is None else devices)
    nd = len(devices)
    unit = nd * nf
    chunk = -(-min(chunk, n_draws) // unit) * unit
    fn, sharding = _engine(settings, devices)
    start_time = time.perf_counter()
    parts = []
    offsets = range(0, n_draws, chunk)
    for offset in progress(offsets, total=len(offsets), desc="PE map", quiet=quiet):
        # The last chunk is padded to the full size so every call reuses one compiled program.
        keys = jax.device_put(draw_keys(key, start + offset, chunk), sharding)
        out = jax.device_get(fn(keys))
        parts.append({k: v[: n_draws - offset] for k, v in out.items()})
    result = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    result["family"] = draw_family(start + np.arange(n_draws), settings)
    result["seconds"] = time.perf_counter() - start_time
    return result


SHARPER_STATEMENT = (
    "in every window, n <= min(K, J) + 1, no frozen play sits at 0, and no three plays are "
    "pairwise twins, where K is the number of distinct non-constant play shapes (outputs equal "
    "up to a constant count once), J the number of samples at which some play moves, and two "
    "plays are twins when |h_i - h_j| is constant on the window"
)


def _counts(rho, pe, sharper) -> dict:
    above = rho >= 1
    below = ~above
    return {
        "n": int(rho.size),
        "assumption_holds": int(above.sum()),
        "pe": int(pe.sum()),
        "theorem_violations": int((above & ~pe).sum()),
        "pe_below_assumption": int((below & pe).sum()),
        "pe_fraction_below_assumption": float((below & pe).sum() / max(int(below.sum()), 1)),
        "sharper_holds": int(sharper.sum()),
        "sharper_holds_not_pe": int((sharper & ~pe).sum()),
        "sharper_fails_pe": int((~sharper & pe).sum()),
    }


def summarise(result: dict, settings: MapSettings) -> dict:
    """The counts a map is judged by, overall and per family.

    A draw is PE when its normalised level exceeds `numerical_tolerance(dtype)`. Theorem 1 of
    the paper predicts `theorem_violations` (ρ >= 1 but not PE) = 0. The sharper condition
    ([`sharper_condition`][], in every window) is necessary for PE, so `sharper_fails_pe` must be
    0 up to rounding; `sharper_holds_not_pe` counts the draws where it is not sufficient.

    **Arguments:** `result` from [`pe_map`][]; its `settings`.

    **Returns:** a JSON-ready dict.
    """
    tol = numerical_tolerance(settings.dtype)
    rho = np.asarray(result["rho"])
    pe = np.asarray(result["c1_normalised"]) > tol
    sharper = np.asarray(result["sharper"])
    fam = np.asarray(result["family"])
    total = _counts(rho, pe, sharper)
    per_family = {
        FAMILIES[f]: _counts(rho[fam == f], pe[fam == f], sharper[fam == f])
        for f in settings.families
    }
    return {
        "tolerance": tol,
        "tolerance_meaning": "a draw is PE when min over windows of lambda_min/lambda_max > tolerance",
        **total,
        "theorem_violations_failing_sharper": int(((rho >= 1) & ~pe & ~sharper).sum()),
        "sharper_condition": {
            "statement": SHARPER_STATEMENT,
            "violations": total["sharper_holds_not_pe"] + total["sharper_fails_pe"],
            "holds_but_not_pe": total["sharper_holds_not_pe"],
            "fails_but_pe": total["sharper_fails_pe"],
        },
        "per_family": per_family,
    }
