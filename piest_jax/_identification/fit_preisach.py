"""Fitting a discrete Preisach model: smoothness-penalised least squares in bounded memory.

**Grid.** In units where the input spans [-1, 1] (u_mid ± u_half), the centres tile the range,
c_m = -1 + (2m + 1)/M with blur δ = 1/M (so equal weights along c give a play up to an affine map),
and the half-widths run up to half the range, r_k = k/K, k = 0..K-1 (as the plain PI grid of
[`uniform_pi`][piest_jax.uniform_pi]). Cells outside the Preisach triangle (|c| - δ ≥ 1 - r) never
switch once the input has been to both ends of its range: after the start they are constants,
indistinguishable from the offset, so their density is fixed at 0 (`triangle`); this also keeps a
held-out block that contains the record's start from being scored on cells no other block sees.

**Normal equations by chunks.** The columns are the blurred relays plus a constant. The record is
cut into chunks of `chunk` samples; a `lax.scan` over the chunks carries the K play states and
adds each chunk's BᵀWB and BᵀWy (W the mask) into one of `n_blocks` contiguous blocks. Memory is
O(chunk·K·M + n_blocks·(K·M)²), independent of the record's length; no T × K·M matrix is formed.

**Smoothness.** The penalty is λ_s·‖D_r μ‖² + λ_s·‖D_c μ‖², D the second differences along the
half-widths and along the centres of the (K, M) density, with λ_s = `smoothness` × tr(BᵀB)/tr(DᵀD)
so that the value does not depend on the data's scale or the grid's size (a tiny ridge keeps the
system definite). When `smoothness` is None it is chosen from a log grid by held-out contiguous
blocks: for each block b the density is solved from the other blocks' normal equations and scored
on block b's output, whose squared error is yᵀy - 2θᵀh + θᵀGθ from that block's own sums, so the
choice needs no second pass over the data. The input of a held-out block still drives the plays
(only its output is held out), as it would when predicting a later part of a record.

**Monotone option.** `monotone=True` constrains μ ≥ 0 (the offset stays free, eliminated first)
and solves the penalised problem by non-negative least squares on a square root of its matrix. A
density ≥ 0 makes the output non-decreasing in the current input for a fixed past, hence
invertible (`Preisach.inverse`).

The solves run in float64 NumPy on the host; only the accumulation runs in JAX.
"""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import scipy.linalg
import scipy.optimize
from jax import lax

from .. import _checks
from .._custom_types import SignalLike
from .._models.preisach import Preisach, relay_chunk
from .._operators.play import Method
from . import covariance as _cov
from . import preisach_covariance
from .uncertainty import Uncertainty

DEFAULT_SMOOTHNESS = tuple(float(v) for v in np.logspace(-7, 1, 9))


class PreisachFit(Uncertainty):
    """The result of [`fit_preisach`][piest_jax.fit_preisach].

    **Fields:**

    - `model`: the fitted [`Preisach`][piest_jax.Preisach] model (original units).
    - `rmse`: the root-mean-square residual over the fitted (unmasked) samples.
    - `smoothness`: the smoothness used (relative units, see the module notes).
    - `candidates`: the smoothness values scored on held-out blocks (empty when given).
    - `held_out_rmse`: the held-out RMSE for each candidate (original units).
    - `n_blocks`: the number of contiguous held-out blocks.
    - `parameter_names` (`"density[k,m]"` for the cells of the Preisach triangle, row-major,
      then `"offset"`), `parameter_values`, `covariance`, `std_errors`, `undetermined`,
      `covariance_method`, `residual_std`: as [`PIFit`][]'s, from the penalised estimate's
      sandwich (`preisach_covariance.py`); None when the fit was asked for no covariance.
    - `effective_parameters`: tr((G + P)⁻¹ G), the number of parameters the smoothed fit
      spends (fewer than the cells); None without a covariance.
    """

    model: Preisach
    rmse: float
    smoothness: float
    candidates: tuple
    held_out_rmse: tuple
    n_blocks: int = eqx.field(static=True)
    effective_parameters: float | None = None


def _second_differences(n: int) -> np.ndarray:
    if n < 3:
        return np.zeros((0, n))
    return np.diff(np.eye(n), 2, axis=0)


def triangle(n_widths: int, n_centres: int) -> np.ndarray:
    """The cells (K, M) of the normalised grid that lie in the Preisach triangle |c| - δ < 1 - r.

    A relay outside it has a switching value beyond the input's range: once the input has been to
    both ends it never switches again, so after the start it is a constant (a part of the offset).

    **Arguments:** `n_widths` K, `n_centres` M.

    **Returns:** a boolean (K, M) array.
    """
    r = np.arange(n_widths) / n_widths
    c = -1.0 + (2.0 * np.arange(n_centres) + 1.0) / n_centres
    return np.abs(c)[None, :] - 1.0 / n_centres < 1.0 - r[:, None] - 1e-12


def triangle_columns(n_widths: int, n_centres: int) -> np.ndarray:
    """The columns of the relays-plus-constant matrix a fit uses: the triangle's cells (raveled,
    row-major) and then the constant, K·M.

    **Arguments:** `n_widths` K, `n_centres` M.

    **Returns:** an integer array of column indices.
    """
    return np.append(np.flatnonzero(triangle(n_widths, n_centres).ravel()), n_widths * n_centres)


def penalty_matrix(n_widths: int, n_centres: int, active=None) -> np.ndarray:
    """DᵀD for the second differences of a (K, M) density along both axes, raveled row-major.

    **Arguments:** `n_widths` K, `n_centres` M; `active` (K, M) booleans: only differences whose
    three cells are all active are kept (default: all cells).

    **Returns:** (K·M, K·M).
    """
    dk = np.kron(_second_differences(n_widths), np.eye(n_centres))
    dm = np.kron(np.eye(n_widths), _second_differences(n_centres))
    D = np.concatenate([dk, dm])
    if active is not None:
        outside = ~np.asarray(active, bool).ravel()
        D = D[~np.any(D[:, outside] != 0, axis=1)]
    return D.T @ D


def normal_equations(
    u, y, weights, half_widths, centres, blur, x0, *, chunk: int = 2048, n_blocks: int = 1, method: Method = "scan"
):
    """Accumulate the normal equations of the relay columns plus a constant, by blocks.

    **Arguments:**

    - `u`, `y`, `weights`: (T,) input, output and sample weights (0 leaves a sample out).
    - `half_widths` (K,), `centres` (M,), `blur` (M,), `x0` (K,): the grid and the plays' states
      before the first sample.
    - `chunk`: samples per scan step; `n_blocks`: contiguous blocks (each a whole number of chunks).
    - `method`: the play bank's method.

    **Returns:** `(G, h, yy, n)`: G (n_blocks, P, P) = BᵀWB, h (n_blocks, P) = BᵀWy,
    yy (n_blocks,) = yᵀWy and n (n_blocks,) = Σ W per block, with P = K·M + 1 (last column the
    constant).
    """
    T = u.shape[0]
    n_chunks = math.ceil(T / chunk)
    pad = n_chunks * chunk - T
    # Padding repeats the last input (the plays do not move) with zero weight.
    up = jnp.concatenate([u, jnp.full((pad,), u[-1], u.dtype)]).reshape(n_chunks, chunk)
    yp = jnp.concatenate([y, jnp.zeros((pad,), y.dtype)]).reshape(n_chunks, chunk)
    wp = jnp.concatenate([weights, jnp.zeros((pad,), weights.dtype)]).reshape(n_chunks, chunk)
    block = (jnp.arange(n_chunks) * n_blocks) // n_chunks
    P = half_widths.shape[0] * centres.shape[0] + 1
    dtype = u.dtype

    def step(carry, inputs):
        x, G, h, yy, n = carry
        uc, yc, wc, b = inputs
        S, x = relay_chunk(uc, x, half_widths, centres, blur, method)
        Sw = S * wc[:, None]
        G = G.at[b].add(Sw.T @ S)
        h = h.at[b].add(Sw.T @ yc)
        yy = yy.at[b].add(jnp.sum(wc * yc * yc))
        n = n.at[b].add(jnp.sum(wc))
        return (x, G, h, yy, n), None

    init = (
        x0,
        jnp.zeros((n_blocks, P, P), dtype),
        jnp.zeros((n_blocks, P), dtype),
        jnp.zeros((n_blocks,), dtype),
        jnp.zeros((n_blocks,), dtype),
    )
    (_, G, h, yy, n), _ = lax.scan(step, init, (up, yp, wp, block))
    return G, h, yy, n


_normal_equations = eqx.filter_jit(normal_equations)


def _solve(G, h, pen, monotone):
    """argmin θᵀGθ - 2hᵀθ + θᵀ pen θ (θ's last entry the free offset), μ ≥ 0 if `monotone`."""
    A = G + pen
    if not monotone:
        try:
            return scipy.linalg.solve(A, h, assume_a="pos")
        except (np.linalg.LinAlgError, scipy.linalg.LinAlgError):
            return np.linalg.lstsq(A, h, rcond=None)[0]
    # Eliminate the free offset (Schur complement), then NNLS on the Cholesky factor.
    a, b = A[:-1, :-1], A[:-1, -1]
    c = max(A[-1, -1], 1e-300)
    As = a - np.outer(b, b) / c
    hs = h[:-1] - b * h[-1] / c
    # A square root of the (positive semi-definite, maybe numerically singular) matrix: As = FᵀF,
    # and Fᵀg = hs on its range, so |Fμ - g|² = μᵀAsμ - 2hsᵀμ + const.
    lam, V = np.linalg.eigh(0.5 * (As + As.T))
    pos = lam > 1e-13 * max(lam.max(), 1e-300)
    F = np.sqrt(lam[pos])[:, None] * V[:, pos].T
    g = (V[:, pos].T @ hs) / np.sqrt(lam[pos])
    mu = scipy.optimize.nnls(F, g, maxiter=50 * len(As))[0]
    return np.append(mu, (h[-1] - b @ mu) / c)


def _sse(theta, G, h, yy):
    return max(float(yy - 2 * theta @ h + theta @ G @ theta), 0.0)


def fit_preisach(
    u: SignalLike,
    y: SignalLike,
    *,
    n_widths: int,
    n_centres: int,
    smoothness: float | None = None,
    mask=None,
    initial_states=None,
    monotone: bool = False,
    candidates=DEFAULT_SMOOTHNESS,
    n_blocks: int = 5,
    chunk: int = 2048,
    method: Method = "auto",
    covariance: str | None = "newey-west",
) -> PreisachFit:
    """Fit a discrete Preisach model to one record by smoothness-penalised least squares.

    The grid spans the input's range (centres) and half its range (half-widths); the density
    solves penalised normal equations accumulated chunk by chunk, so the memory does not grow with
    the record. The smoothness is chosen on held-out contiguous blocks when not given.

    **Arguments:**

    - `u`, `y`: the input and output, (T,).
    - `n_widths`: K, the number of half-widths (plays), ≥ 1.
    - `n_centres`: M, the number of relay centres per half-width, ≥ 2.
    - `smoothness`: the second-difference penalty (relative: × tr(BᵀB)/tr(DᵀD)), ≥ 0; None
      chooses it from `candidates` by held-out blocks.
    - `mask`: (T,) sample weights, 0 to leave a sample out of the fit (it still drives the plays).
    - `initial_states`: the plays' states before the first sample, scalar or (K,), in input units;
      None starts them relaxed at u_0.
    - `monotone`: constrain the density to μ ≥ 0 (output non-decreasing in the current input).
    - `candidates`: the smoothness values tried when `smoothness` is None.
    - `n_blocks`: contiguous blocks for the held-out choice (≥ 2 when choosing).
    - `chunk`: samples per accumulation step (memory ∝ chunk · K · M).
    - `method`: the play bank's method (`"auto"`: the compiled kernel on CPU when built).
    - `covariance`: `"newey-west"` (default), `"gauss-newton"` or None: the density's and the
      offset's covariance over the noise at the chosen smoothness (`preisach_covariance.py`;
      one more pass over the record).

    **Returns:** a [`PreisachFit`][piest_jax.PreisachFit] with the model in the data's units.
    """
    for name, v, lo in (
        ("n_widths", n_widths, 1),
        ("n_centres", n_centres, 2),
        ("n_blocks", n_blocks, 1),
        ("chunk", chunk, 1),
    ):
        if not _checks.is_whole(v) or v < lo:
            raise ValueError(f"`{name}` must be an integer >= {lo}, got {v!r}")
    if covariance is not None and covariance not in _cov.METHODS:
        raise ValueError(f"unknown covariance {covariance!r}; choose one of {_cov.METHODS} or None")
    u = np.asarray(_checks.finite(_checks.signal(u, "u"), "u"), dtype=np.float64)
    y = np.asarray(_checks.finite(_checks.signal(y, "y"), "y"), dtype=np.float64)
    if u.shape != y.shape:
        raise ValueError(f"`u` and `y` must have the same length, got {u.shape[0]} and {y.shape[0]}")
    T = u.shape[0]
    if mask is None:
        w = np.ones(T)
    else:
        w = np.asarray(mask, dtype=np.float64)
        if w.shape != (T,) or not np.all(np.isfinite(w)) or np.any(w < 0):
            raise ValueError(f"`mask` must be (T,) = ({T},) finite non-negative weights")
    # Plain ints: a NumPy integer would reach jit as a traced shape.
    K, M, n_blocks = int(n_widths), int(n_centres), int(n_blocks)
    used = int(np.count_nonzero(w))
    n_coef = int(triangle(K, M).sum()) + 1
    if used < n_coef:
        raise ValueError(
            f"a {K} × {M} grid has {n_coef} coefficients (its triangle and the offset) "
            f"but only {used} samples are fitted: use a coarser grid or a longer record"
        )
    if smoothness is None:
        cands = tuple(float(c) for c in candidates)
        if not cands or not all(np.isfinite(c) and c >= 0 for c in cands):
            raise ValueError("`candidates` must be non-empty, finite and non-negative")
        if n_blocks < 2:
            raise ValueError("choosing the smoothness needs `n_blocks` >= 2")
    else:
        if not (np.isfinite(smoothness) and smoothness >= 0):
            raise ValueError(f"`smoothness` must be finite and >= 0, got {smoothness!r}")
        cands = ()
    u_mid, u_half = 0.5 * (u.max() + u.min()), 0.5 * (u.max() - u.min())
    if u_half <= 0:
        raise ValueError("`u` is constant: a Preisach model needs the input to move")
    y_mid = 0.5 * (y.max() + y.min())
    y_half = max(0.5 * (y.max() - y.min()), np.finfo(float).tiny)
    x0 = (
        np.full(K, u[0])
        if initial_states is None
        else np.broadcast_to(
            np.asarray(
                _checks.finite(_checks.per_play(initial_states, K, "initial_states"), "initial_states"),
                dtype=np.float64,
            ),
            (K,),
        )
    )
    # Sample-level blocks need at least one chunk each.
    chunk = int(max(1, min(chunk, math.ceil(T / n_blocks))))
    nb = min(n_blocks, math.ceil(T / chunk))

    dtype = jnp.result_type(float)
    r = np.arange(K) / K
    c = -1.0 + (2.0 * np.arange(M) + 1.0) / M
    d = np.full(M, 1.0 / M)
    G, h, yy, n = jax.device_get(
        _normal_equations(
            jnp.asarray((u - u_mid) / u_half, dtype),
            jnp.asarray((y - y_mid) / y_half, dtype),
            jnp.asarray(w, dtype),
            jnp.asarray(r, dtype),
            jnp.asarray(c, dtype),
            jnp.asarray(d, dtype),
            jnp.asarray((x0 - u_mid) / u_half, dtype),
            chunk=chunk,
            n_blocks=nb,
            method=method,
        )
    )
    G, h, yy, n = (np.asarray(a, dtype=np.float64) for a in (G, h, yy, n))
    Gt, ht, yyt, nt = G.sum(0), h.sum(0), yy.sum(), n.sum()

    # Only the cells in the Preisach triangle are fitted (the others stay 0); the last column of
    # the normal equations is the offset.
    active = triangle(K, M)
    keep = triangle_columns(K, M)
    G, h = G[:, keep][:, :, keep], h[:, keep]
    Gt, ht = G.sum(0), h.sum(0)
    n_act = int(active.sum())
    D = penalty_matrix(K, M, active)[np.ix_(active.ravel(), active.ravel())]
    scale = np.trace(Gt[:-1, :-1]) / max(np.trace(D), 1.0)
    ridge = 1e-12 * np.trace(Gt[:-1, :-1]) / n_act

    def pen(lam):
        p = np.zeros_like(Gt)
        p[:-1, :-1] = lam * scale * D + ridge * np.eye(n_act)
        return p

    scores = []
    for lam in cands:
        sse = 0.0
        for b in range(nb):
            theta = _solve(Gt - G[b], ht - h[b], pen(lam), monotone)
            sse += _sse(theta, G[b], h[b], yy[b])
        scores.append(float(np.sqrt(sse / max(nt, 1.0)) * y_half))
    lam = float(smoothness) if smoothness is not None else cands[int(np.argmin(scores))]
    theta = _solve(Gt, ht, pen(lam), monotone)
    rmse = float(np.sqrt(_sse(theta, Gt, ht, yyt) / max(nt, 1.0)) * y_half)
    mu = np.zeros((K, M))
    mu[active] = theta[:-1]

    model = Preisach(
        half_widths=jnp.asarray(r * u_half, dtype),
        centres=jnp.asarray(c * u_half + u_mid, dtype),
        density=jnp.asarray(mu * y_half, dtype),
        offset=jnp.asarray(y_mid + y_half * theta[-1], dtype),
        initial_states=None if initial_states is None else jnp.asarray(x0, dtype),
        blur=jnp.asarray(d * u_half, dtype),
        method=method,
    )
    fields = {}
    if covariance is not None:
        grid = (r, c, d, (x0 - u_mid) / u_half)
        fields = _covariance(
            covariance,
            model,
            theta,
            Gt,
            pen(lam),
            active,
            monotone,
            u,
            y,
            w,
            (u_mid, u_half, y_mid, y_half),
            grid,
            chunk,
            method,
        )
    return PreisachFit(
        model=model, rmse=rmse, smoothness=lam, candidates=cands, held_out_rmse=tuple(scores), n_blocks=nb, **fields
    )


def _covariance(method, model, theta, G, pen, active, monotone, u, y, w, scales, grid, chunk, play_method) -> dict:
    """`PreisachFit`'s covariance fields (see `preisach_covariance.py`)."""
    u_mid, u_half, y_mid, y_half = scales
    e = (y - np.asarray(model(u), np.float64)) / y_half
    used = w > 0
    free = np.ones(theta.shape[0], bool)
    if monotone:
        free[:-1] = theta[:-1] > 0
    blocks = window = None
    if method == "newey-west":
        window = _cov.bandwidth(e[used])
        keep = triangle_columns(*active.shape)
        dtype = jnp.result_type(float)
        half_widths, centres, blur, x0 = (jnp.asarray(a, dtype) for a in grid)
        blocks = np.asarray(
            preisach_covariance.score_blocks(
                jnp.asarray((u - u_mid) / u_half, dtype),
                jnp.asarray(w * e, dtype),
                half_widths,
                centres,
                blur,
                x0,
                jnp.asarray(keep),
                window,
                max(int(chunk), window),
                play_method,
            ),
            np.float64,
        )
    K, M = active.shape
    names = [f"density[{k},{m}]" for k in range(K) for m in range(M) if active[k, m]] + ["offset"]
    out = preisach_covariance.fields(
        method, G, G + pen, free, int(used.sum()), float(np.sum(w * e * e)), y_half, names, blocks, window
    )
    values = np.append(theta[:-1] * y_half, y_mid + y_half * theta[-1])
    return {**out, "parameter_values": jnp.asarray(values)}
