"""The analytic inverse of a play-based PI operator.

For y = Σ_j w_j H_{r_j}[u] with 0 = r_1 < ... < r_n, write W_i = w_1 + ... + w_i (the slope of the
loading curve after the i-th play has started to move). When every W_i > 0 the inverse is again a
play-based PI operator, u = Σ_i w'_i H_{r'_i}[y], with

    r'_i = Σ_{j<=i} w_j (r_i - r_j),     w'_1 = 1 / w_1,     w'_i = -w_i / (W_i W_{i-1}),

and its plays' states are tied to the forward plays' states x_j at every instant by

    x'_i = W_i x_i + Σ_{j>i} w_j x_j,

which, applied at t = 0, gives initial states consistent with the forward operator's. That tie
holds for states some input history can produce, |x_{i+1} - x_i| <= r_{i+1} - r_i (relaxed states,
all zero, are such); other initial states are rejected, since no inverse can be exact for them.
"""

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .. import _checks


def inverse_problem(thresholds, weights) -> str | None:
    """Why a PI operator with these (concrete) thresholds and weights has no analytic inverse,
    or None: it needs r_1 = 0 and every cumulative weight w_1 + ... + w_i positive."""
    r = np.asarray(thresholds, np.float64)
    W = np.cumsum(np.asarray(weights, np.float64))
    if r[0] != 0:
        return f"the analytic inverse needs r_1 = 0 (a play with zero threshold); the smallest threshold is {r[0]:.6g}"
    if np.any(W <= 0):
        i = int(np.argmax(W <= 0))
        return (
            "the PI operator is not invertible: the cumulative weights w_1 + ... + w_i must "
            f"stay positive, but at i = {i + 1} they are {W[i]:.6g}"
        )
    return None


def _cumulative_weights(r, w):
    W = jnp.cumsum(w)
    if _checks.is_concrete(W) and _checks.is_concrete(r):
        problem = inverse_problem(r, w)
        if problem is not None:
            raise ValueError(problem)
        return W
    bad = (r[0] != 0) | jnp.any(W <= 0)
    return eqx.error_if(W, bad, "the PI operator is not invertible: need r_1 = 0 and cumulative weights > 0")


def _admissible(r, x):
    gap = jnp.abs(jnp.diff(x)) - jnp.diff(r)
    slack = 64 * jnp.finfo(r.dtype).eps * (1 + jnp.max(jnp.abs(r)) + jnp.max(jnp.abs(x)))
    if _checks.is_concrete(gap):
        if np.any(np.asarray(gap) > float(slack)):
            i = int(np.argmax(np.asarray(gap)))
            raise ValueError(
                "the initial states cannot be reached by any input history, so no inverse is exact "
                f"for them: |x_{i + 2} - x_{i + 1}| exceeds r_{i + 2} - r_{i + 1} "
                "(admissible states satisfy |x_(i+1) - x_i| <= r_(i+1) - r_i)"
            )
        return x
    return eqx.error_if(x, jnp.any(gap > slack), "initial states are not admissible")


def inverse_parameters(r, w, x):
    """Thresholds, weights and initial states of the inverse of the PI operator (r, w, x).

    The closed forms of this module's docstring; [`PIOperator.inverse`][] wraps them in an operator.
    Raises `ValueError` (or an `eqx.error_if` error under `jit`) when the operator is not
    invertible or its initial states are not admissible.
    """
    W = _cumulative_weights(r, w)
    x = _admissible(r, x) if w.shape[0] > 1 else x
    # r'_i = W_i r_i - Σ_{j<=i} w_j r_j
    r_inv = W * r - jnp.cumsum(w * r)
    W_prev = jnp.concatenate([jnp.ones_like(W[:1]), W[:-1]])
    w_inv = jnp.where(jnp.arange(w.shape[0]) == 0, 1.0 / w[0], -w / (W * W_prev))
    # Σ_{j>i} w_j x_j, a reversed cumulative sum shifted by one
    tail = jnp.cumsum((w * x)[::-1])[::-1] - w * x
    x_inv = W * x + tail
    for what, v in (("thresholds", r_inv), ("weights", w_inv), ("initial states", x_inv)):
        _in_range(r, w, what, v)
    return r_inv, w_inv, x_inv


def _in_range(r, w, what: str, v) -> None:
    # Huge but finite thresholds or weights (or tiny weights) make the closed forms' products and
    # reciprocals overflow; say that, rather than let the result's NaN/inf check blame the inverse.
    if not _checks.is_concrete(v) or bool(jnp.all(jnp.isfinite(v))):
        return
    r, w = np.asarray(r), np.abs(np.asarray(w))
    raise ValueError(
        f"the model is out of the range of {np.asarray(v).dtype.name}: the inverse's {what} "
        f"overflow (thresholds up to {np.max(np.abs(r)):.3g}, weights from {np.min(w):.3g} to "
        f"{np.max(w):.3g}); rescale the model's units"
    )
