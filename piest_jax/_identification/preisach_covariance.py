"""The covariance of a Preisach fit's density and offset: the sandwich of a penalised
least-squares estimate, accumulated chunk by chunk.

The estimate θ = (G + P)⁻¹ Bᵀ W y (normalised units, `fit_preisach`: B the blurred relays of the
Preisach triangle plus a constant, W the sample weights, P the smoothness penalty) is linear in
y, so its covariance over the noise is exactly A⁻¹ Ω A⁻¹ with A = G + P and Ω the covariance of
the scores Bᵀ W e:

- **Gauss-Newton** (white residuals): Ω = σ² G, σ² = Σe²/(N − edf), edf = tr(A⁻¹ G) the
  effective number of parameters (the penalty makes it smaller than their count);
- **Newey-West** (the default): Ω from overlapping block sums of the scores gₜ = Bₜ wₜ eₜ with
  the PI fit's block length rule (`covariance.bandwidth`), times N/(N − edf).

This is the estimate's spread over noise draws at the chosen smoothness, the quantity the
calibration tests check; it leaves out the bias the smoothing brings. With the non-negative
density (`monotone`) the cells the constraint holds at 0 are not estimated there: the covariance
is that of the other cells and the offset (the active set fixed), and theirs is 0.

**Undetermined.** A cell whose relay never switches on the fitted samples, or whose relays switch
only together with others (G's numerical rank, as `covariance.estimate_moments` judges it, on
the free cells), is determined by the smoothness penalty alone, not by the record: it is
undetermined, its standard error infinite. The offset is also undetermined when its standard
error exceeds half the output range.
"""

import math

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jax import lax

from .._models.preisach import relay_chunk
from .._operators.play import Method
from . import covariance as _cov


@eqx.filter_jit
def score_blocks(u, e, half_widths, centres, blur, x0, keep, window: int, chunk: int, method: Method = "scan"):
    """Σ_t W_t W_tᵀ of the overlapping `window`-sample sums W_t of the scores g_t = B_t e_t.

    **Arguments:** `u` (T,) and the weighted residuals `e` (T,), normalised; the grid
    (`half_widths` (K,), `centres` (M,), `blur` (M,)) and the plays' states `x0` (K,); `keep`
    (p,) the indices of the columns (cells, raveled, then the constant) in use; `window`, `chunk`
    samples; `method`, the play bank's method.

    **Returns:** (p, p).
    """
    T = u.shape[0]
    p = keep.shape[0]

    def body(carry, inputs):
        x, tail, blocks = carry
        uu, ee, ii = inputs
        S, x = relay_chunk(uu, x, half_widths, centres, blur, method)
        W, tail = _cov.block_sums(tail, S[:, keep] * ee[:, None], ii, T)
        return (x, tail, blocks + W.T @ W), None

    data = (_cov.chunked(u, u[-1], chunk), _cov.chunked(e, 0.0, chunk), _cov.chunked(jnp.arange(T), T, chunk))
    init = (x0, jnp.zeros((window, p), u.dtype), jnp.zeros((p, p), u.dtype))
    (_, _, blocks), _ = lax.scan(body, init, data)
    return blocks


def fields(
    method: str, G, A, free, n: int, ete: float, y_half: float, names, blocks=None, window: int | None = None
) -> dict:
    """The covariance fields (as [`PIFit`][]'s, values aside) in the data's units.

    **Arguments:** `method`; `G` (p, p) the data's normal matrix and `A` (p, p) with the penalty
    (normalised units, the offset last); `free` (p,) booleans, the entries the constraint does
    not hold; `n` the fitted samples; `ete` Σe² (normalised); `y_half` the output's half range;
    `names` (p,) the parameters' names; for Newey-West `blocks` (p, p) from [`score_blocks`][]
    and its `window`.
    """
    p = G.shape[0]
    idx = np.flatnonzero(free)
    Gf, Af = G[np.ix_(idx, idx)], A[np.ix_(idx, idx)]
    Ainv = np.linalg.pinv(0.5 * (Af + Af.T))
    edf = float(np.trace(Ainv @ Gf))
    dof = n - edf
    cov_f = np.zeros((idx.size, idx.size))
    sigma = float("nan")
    if dof >= 1:
        sigma = math.sqrt(ete / dof)
        if method == "gauss-newton":
            meat = sigma**2 * Gf
        else:
            assert blocks is not None and window is not None  # Newey-West's, given with it
            meat = blocks[np.ix_(idx, idx)] / window * n / (n - window + 1) * n / dof
        cov_f = Ainv @ meat @ Ainv
        cov_f = 0.5 * (cov_f + cov_f.T)
    # The free entries the data alone do not determine: G's numerical rank on them.
    deficient = _cov.gram_deficient(Gf, n)
    cov = np.zeros((p, p))
    cov[np.ix_(idx, idx)] = cov_f * y_half**2
    se = np.sqrt(np.maximum(np.diag(cov), 0.0))
    undetermined = np.zeros(p, bool)
    undetermined[idx] = deficient | (dof < 1)
    undetermined[-1] |= not se[-1] < _cov.RELATIVE_LIMIT * y_half
    se[undetermined] = np.inf
    return dict(
        parameter_names=tuple(names),
        covariance=jnp.asarray(cov),
        std_errors=jnp.asarray(se),
        undetermined=jnp.asarray(undetermined),
        covariance_method=method,
        residual_std=sigma * y_half,
        effective_parameters=edf,
    )
