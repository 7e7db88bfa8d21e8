"""The Prandtl-Ishlinskii operator, a weighted sum of plays (paper eq. 3)."""

import abc

import equinox as eqx
import jax
import jax.numpy as jnp
from jax import lax
from jaxtyping import Array

from .. import _checks
from .._custom_types import Regressor, Signal, SignalLike, States, Thresholds, Weights
from .inverse import inverse_parameters
from .play import METHODS, Method, _bank, _uses_kernel, play_step, resolved


# Jitted at module level so that eager calls with the same shapes reuse one compiled program (an
# eager scan over a fresh closure would compile, and keep, a new one on every call).
@jax.jit
def _pi_scan(u: Array, r: Array, w: Array, x0: Array) -> Array:
    def step(x, ut):
        x = play_step(x, ut, r)
        return x, jnp.dot(w, x)

    _, y = lax.scan(step, x0, u)
    return y


class AbstractHysteresisOperator(eqx.Module):
    """A rate-independent hysteresis operator acting on one sampled signal.

    Subclasses give the output for one input signal; batching is the caller's `jax.vmap`.
    """

    @abc.abstractmethod
    def __call__(self, u: SignalLike) -> Signal:
        """The operator's output for the input `u` (T,)."""


class PIOperator(AbstractHysteresisOperator):
    """y = Σ_j ω_j H_{r_j}[u], a weighted sum of plays with thresholds 0 <= r_1 < ... < r_n.

    **Arguments:**

    - `thresholds`: (n,), non-negative and strictly increasing. The paper has r_1 = 0, which makes
      the first play the identity and the operator invertible; it is not required here.
    - `weights`: (n,); a scalar for one play (`PIOperator(0.0, 1.0)`).
    - `initial_states`: the plays' states before the first sample, a scalar or (n,); they need not
      be zero (paper eq. 2).
    - `method`: how the plays are run, `"auto"` (the default: the compiled kernel on a CPU),
      `"scan"`, `"associative"` or `"kernel"` (see [`play`][piest_jax.play]).

    Bad shapes raise `ValueError` when the operator is built; negative or unsorted thresholds raise
    `ValueError` for concrete values and an `eqx.error_if` runtime error under `jit`.
    """

    thresholds: Thresholds
    weights: Weights
    initial_states: States
    method: Method = eqx.field(static=True, default="auto")

    def __init__(self, thresholds, weights, initial_states=0.0, *, method: Method = "auto"):
        r = _checks.thresholds(thresholds, "thresholds", sorted_=True)
        if r.ndim == 0:
            r = r[None]
        n = r.shape[0]
        w = _checks.per_play(weights, n, "weights")
        if w.ndim == 0 and n > 1:
            raise ValueError(f"`weights` must be a vector of {n} entries, got a scalar")
        # One play: a scalar weight goes with a scalar threshold, as for the initial state.
        w = jnp.broadcast_to(w, (n,))
        x0 = _checks.per_play(initial_states, n, "initial_states")
        if method not in METHODS:
            raise ValueError(f"unknown play method {method!r}; choose one of {METHODS}")
        dtype = jnp.result_type(r, w, x0)
        self.thresholds = r.astype(dtype)
        self.weights = _checks.finite(w, "weights").astype(dtype)
        self.initial_states = jnp.broadcast_to(_checks.finite(x0, "initial_states"), (n,)).astype(dtype)
        self.method = method

    @property
    def n_plays(self) -> int:
        """The number of plays n."""
        return self.thresholds.shape[0]

    def _input(self, u) -> Array:
        u = _checks.signal(u)
        dtype = jnp.result_type(u, self.thresholds)
        if not _uses_kernel(self.method, dtype=dtype):
            u = _checks.finite(u, "u")
        return u.astype(dtype)

    def regressor(self, u: SignalLike) -> Regressor:
        """The play outputs H (T, n), the regressor of the weight-estimation problem (eq. 4).

        **Arguments:** `u`, the input (T,).

        **Returns:** H with H[t, j] = H_{r_j}[u](t), so that `self(u) == H @ weights`.
        """
        u = self._input(u)
        return _bank(u, self.thresholds, self.initial_states, self.method)

    def __call__(self, u: SignalLike) -> Signal:
        """The PI output y (T,), without materialising the (T, n) regressor.

        **Arguments:** `u`, the input (T,).

        **Returns:** y (T,).
        """
        u = self._input(u)
        method = resolved(self.method, dtype=u.dtype)
        if method == "associative":
            return _bank(u, self.thresholds, self.initial_states, method) @ self.weights
        if method == "kernel":
            from . import kernel as _kernel

            return _kernel.pi_output(u, self.thresholds, self.initial_states, self.weights)
        return _pi_scan(u, self.thresholds, self.weights, self.initial_states)

    def final_states(self, u: SignalLike) -> States:
        """The plays' states after the last sample of `u`, to continue a run from where it ended.

        **Arguments:** `u`, the input (T,).

        **Returns:** (n,) states; `PIOperator(r, w, final_states)` continues the run seamlessly.
        """
        return self.regressor(u)[-1]

    def inverse(self) -> "PIOperator":
        """The analytic inverse operator; see [`inverse`][]."""
        return PIOperator(*inverse_parameters(self.thresholds, self.weights, self.initial_states), method=self.method)


def inverse(op: PIOperator) -> PIOperator:
    """The inverse PI operator, so that `op(inverse(op)(v)) == v` for any signal v.

    **Arguments:**

    - `op`: a [`PIOperator`][] with r_1 = 0 whose cumulative weights w_1 + ... + w_i are all
      positive (its loading curve is strictly increasing).

    **Returns:** a `PIOperator` with thresholds r', weights w' and initial states from the closed
    forms of the inverse (module `inverse` of the operators). Raises `ValueError` (or an
    `eqx.error_if` error under `jit`) when the operator is not invertible or its initial states are
    not admissible.
    """
    return op.inverse()
