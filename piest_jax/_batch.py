"""Batch estimation experiments: one jitted `vmap` over many settings.

Each batch member has its own input, true weights (constant or changing over time), estimator
settings (P0, forgetting factor, gain, ...) and measurement-noise level; the estimator family is
fixed per call by `make_estimator`, a function from one member's settings to an estimator. The
result holds the convergence statistics of every member.
"""

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int, PRNGKeyArray

from ._estimators import AbstractEstimator, estimate
from ._pi import PIOperator


class BatchStats(eqx.Module):
    """Convergence statistics of a batch, one row per member.

    **Fields:**

    - `final_weights` (B, n): the estimate after the last sample.
    - `final_error` (B, n): final estimate minus the final true weights.
    - `converged_index` (B,): the first sample after which every weight stays within `rtol` of
      its final true value; T when it never settles.
    - `rms_prediction_error` (B,): RMS of the a-priori prediction error over the second half.
    - `finite` (B,): whether the whole trajectory stayed finite.
    """

    final_weights: Float[Array, "batch n"]
    final_error: Float[Array, "batch n"]
    converged_index: Int[Array, " batch"]
    rms_prediction_error: Float[Array, " batch"]
    finite: Bool[Array, " batch"]


def _settle_index(weights, truth, rtol):
    ok = jnp.all(jnp.abs(weights - truth) <= rtol * jnp.abs(truth), axis=1)
    idx = jnp.arange(ok.shape[0])
    last_bad = jnp.max(jnp.where(ok, -1, idx))
    return jnp.where(ok[-1], last_bad + 1, ok.shape[0])


@eqx.filter_jit
def run_batch(
    make_estimator: Callable[..., AbstractEstimator],
    settings,
    inputs: Float[Array, "batch time"],
    true_weights: Float[Array, "batch n"] | Float[Array, "batch time n"],
    noise_std: Float[Array, " batch"],
    thresholds: Float[Array, " n"],
    *,
    key: PRNGKeyArray,
    rtol: float = 0.01,
) -> BatchStats:
    """Simulate and estimate every member of a batch in one compiled `vmap`.

    **Arguments:**

    - `make_estimator`: settings of one member → estimator, e.g.
      `lambda s: ForgettingRLS(s["P0"], s["forgetting"])`.
    - `settings`: a pytree whose leaves have a leading batch axis B.
    - `inputs`: (B, T) input signals.
    - `true_weights`: (B, n), or (B, T, n) for weights that change over time (then
      y_k = h_kᵀ W_k and errors refer to the final weights W_T).
    - `noise_std`: (B,) standard deviation of white Gaussian noise added to y.
    - `thresholds`: (n,) shared by the batch.
    - `key`: PRNG key, split once per member.
    - `rtol`: relative tolerance for `converged_index`.

    **Returns:** a [`BatchStats`][].
    """
    inputs = jnp.asarray(inputs)
    B, T = inputs.shape
    true_weights = jnp.asarray(true_weights, inputs.dtype)
    if true_weights.ndim not in (2, 3) or true_weights.shape[0] != B:
        raise ValueError(
            f"`true_weights` must be (B, n) or (B, T, n) with B = {B}, got {true_weights.shape}"
        )
    noise_std = jnp.broadcast_to(jnp.asarray(noise_std, inputs.dtype), (B,))
    keys = jax.random.split(key, B)

    def one(setting, u, w, sigma, k):
        w_path = jnp.broadcast_to(w, (T, w.shape[-1]))
        H = PIOperator(thresholds, w_path[-1]).regressor(u)
        if H.shape[1] != w_path.shape[1]:
            raise ValueError(
                f"{w_path.shape[1]} true weights for {H.shape[1]} thresholds"
            )
        y = jnp.sum(H * w_path, axis=1) + sigma * jax.random.normal(k, (T,), H.dtype)
        res = estimate(make_estimator(setting), H, y)
        finite = jnp.all(jnp.isfinite(res.weights)) & jnp.all(jnp.isfinite(res.gain_trace))
        final = res.weights[-1]
        half = res.error[T // 2 :]
        return BatchStats(
            final,
            final - w_path[-1],
            _settle_index(res.weights, w_path[-1], rtol),
            jnp.sqrt(jnp.mean(half**2)),
            finite,
        )

    return jax.vmap(one)(settings, inputs, true_weights, noise_std, keys)
