"""The generalized PI model: a PI operator followed by a saturating output function.

    y = g(P[u]),   g(v) = offset + Σ_k a_k tanh((v - c_k)/s_k),   a_k > 0, s_k > 0,

with P = Σ_j w_j H_{r_j} the PI operator (the one play recurrence of the operators). A PI model
with positive weights grows without bound with its input; magnetic B-H loops and piezos at large
drive saturate. The output function bends the PI's loops into saturating ones while keeping the
PI's memory (wiping-out, rate independence, congruent loops in v = P[u]).

**Why this g.** Each term is strictly increasing and bounded, and the amplitudes and scales are
stored as logarithms, so for *any* parameter values g is strictly increasing (g' > 0 everywhere)
and bounded: |y - offset| < A = Σ a_k for every input, however large. That is what the inverse
needs and what saturation means. One term is the classic anhysteretic tanh; a second lets the
knee's sharpness and the approach to saturation differ (a steep part and a slow one, as domain-
wall motion and rotation in a magnetic core). A superposition of dead-zones (Kuhnen's modified PI)
is monotone too but unbounded, so it cannot saturate; a polynomial is neither.

**The inverse.** For a target y in (offset - A, offset + A), put z = (y - offset)/A. At
v_k = c_k + s_k atanh(z) term k equals z, and g is the amplitude-weighted mean of the terms, so
the solution of g(v) = y lies in [min_k v_k, max_k v_k]: a bisection there (elementwise, over all
samples at once) finds it; with one term the bracket is a point and the inverse is the closed form
c + s atanh(z). Then P⁻¹ (the PI operator's analytic inverse) gives the input: u = P⁻¹[g⁻¹(y)],
the compensator. A target outside the open range cannot be reached by any input and is refused.

**Scale.** (w, c, s) and (λw, λc, λs) give the same model for any λ > 0 (the PI's output unit is
free); [`GeneralizedPI.normalised`][piest_jax.GeneralizedPI.normalised] picks s_1 = 1.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jaxtyping import Array, ArrayLike, Float

from .. import _checks
from .._custom_types import Scalar, Signal, SignalLike
from .._operators.inverse import inverse_problem
from .._operators.pi import PIOperator
from .._operators.play import play_step
from .model import AbstractHysteresisModel

Terms = Float[Array, " terms"]


def _positive_vector(x, name: str) -> Array:
    x = jnp.atleast_1d(_checks.as_float_array(x, name))
    if x.ndim != 1 or x.shape[0] < 1:
        raise ValueError(f"`{name}` must be a non-empty vector, got shape {x.shape}")
    if _checks.is_concrete(x):
        v = np.asarray(x)
        if not np.all(np.isfinite(v)) or np.any(v <= 0):
            raise ValueError(f"`{name}` must be positive and finite, got {v.tolist()}")
        return x
    return eqx.error_if(x, ~jnp.all(jnp.isfinite(x) & (x > 0)), f"`{name}` must be positive")


# Compiled as one program: run op by op, a new shape of `v` compiled each of its operations.
@jax.jit
def output_function(v: Array, log_amplitudes: Array, centres: Array, log_scales: Array, offset) -> Array:
    """g(v) = offset + Σ_k a_k tanh((v - c_k)/s_k) elementwise, with a = exp(log a), s = exp(log s).

    **Arguments:** `v`, any shape; `log_amplitudes`, `centres`, `log_scales` (K,); `offset`.

    **Returns:** g(v), the shape of `v`.
    """
    x = (v[..., None] - centres) * jnp.exp(-log_scales)
    return offset + jnp.tanh(x) @ jnp.exp(log_amplitudes)


class GeneralizedPI(AbstractHysteresisModel):
    """A generalized PI model y = g(P[u]): a [`PIOperator`][] P, then a saturating output function.

    g(v) = offset + Σ_k a_k tanh((v - c_k)/s_k) is strictly increasing and bounded for every
    parameter value (see the module notes), so the model saturates at offset ± Σ a_k and, when P
    is invertible, so is the model.

    **Arguments:**

    - `pi`: the [`PIOperator`][] (thresholds, weights, the plays' initial states).
    - `amplitudes` (K,): a_k > 0 (stored as log a).
    - `centres` (K,): c_k, in the PI output's units.
    - `scales` (K,): s_k > 0, in the PI output's units (stored as log s).
    - `offset`: the output's centre.

    `__call__` takes one input signal (T,); batch with `jax.vmap`. Non-positive amplitudes or
    scales, or vectors of different lengths, raise `ValueError`.
    """

    pi: PIOperator
    log_amplitudes: Terms
    centres: Terms
    log_scales: Terms
    offset: Scalar

    def __init__(self, pi: PIOperator, amplitudes, centres, scales, offset=0.0):
        if not isinstance(pi, PIOperator):
            raise ValueError(f"`pi` must be a PIOperator, got {type(pi).__name__}")
        a = _positive_vector(amplitudes, "amplitudes")
        s = _positive_vector(scales, "scales")
        c = jnp.atleast_1d(_checks.as_float_array(centres, "centres"))
        k = a.shape[0]
        for name, v in (("centres", c), ("scales", s)):
            if v.shape != (k,):
                raise ValueError(f"`{name}` must have {k} entries (one per amplitude), got shape {v.shape}")
        off = _checks.as_float_array(offset, "offset")
        if off.ndim != 0:
            raise ValueError(f"`offset` must be a scalar, got shape {off.shape}")
        dtype = jnp.result_type(pi.weights, a, c, s, off)
        self.pi = pi
        self.log_amplitudes = jnp.log(a).astype(dtype)
        self.centres = _checks.finite(c, "centres").astype(dtype)
        self.log_scales = jnp.log(s).astype(dtype)
        self.offset = _checks.finite(off, "offset").astype(dtype)

    @property
    def structure(self) -> str:
        """`"gpi"`, the name model files give this structure."""
        return "gpi"

    @property
    def n_plays(self) -> int:
        """The number of plays n."""
        return self.pi.n_plays

    @property
    def n_terms(self) -> int:
        """The number of tanh terms K."""
        return self.centres.shape[0]

    @property
    def amplitudes(self) -> Terms:
        """a_k = exp(log a_k)."""
        return jnp.exp(self.log_amplitudes)

    @property
    def scales(self) -> Terms:
        """s_k = exp(log s_k)."""
        return jnp.exp(self.log_scales)

    def output_range(self) -> tuple[Scalar, Scalar]:
        """The open interval (offset - Σ a_k, offset + Σ a_k) the output never leaves.

        **Returns:** `(lo, hi)`, scalars.
        """
        total = jnp.sum(self.amplitudes)
        return self.offset - total, self.offset + total

    def output_function(self, v: Array) -> Array:
        """g(v), elementwise: the output for a PI output `v` (any shape).

        **Arguments:** `v`, PI outputs.

        **Returns:** g(v), the shape of `v`.
        """
        v = jnp.asarray(v, self.centres.dtype)
        return output_function(v, self.log_amplitudes, self.centres, self.log_scales, self.offset)

    def output_inverse(self, y: ArrayLike, n_iter: int = 80) -> Array:
        """g⁻¹(y) elementwise, for targets inside `output_range()` (not checked here).

        **Arguments:** `y`, targets (any shape); `n_iter`, bisection steps (each halves the
        bracket [min_k v_k, max_k v_k] of the module notes; with one term it is a point).

        **Returns:** v with g(v) = y, the shape of `y`.
        """
        return _output_inverse(self, jnp.asarray(y, self.centres.dtype), n_iter)

    def init_state(self, u0):
        """The plays' states before the first sample (the model's own)."""
        return self.pi.initial_states

    def step(self, state, u):
        """One sample: the plays' states after the input `u`, and the output g(P) there."""
        x = play_step(state, u, self.pi.thresholds)
        return x, self.output_function(jnp.dot(self.pi.weights, x))

    def with_state(self, state) -> "GeneralizedPI":
        """The same model with its plays started from `state`."""
        return self.with_initial_states(state)

    def __call__(self, u: SignalLike, state=None) -> Signal:
        """The model output g(P[u]) (T,) for one input signal `u` (T,), from `state` (the plays'
        states; default the model's own)."""
        m = self if state is None else self.with_state(state)
        return m.output_function(m.pi(u))

    def final_state(self, u: SignalLike, state=None):
        """The plays' states after the last sample of `u`."""
        m = self if state is None else self.with_state(state)
        return m.pi.final_states(u)

    def with_initial_states(self, play_states) -> "GeneralizedPI":
        """The same model with its plays started from `play_states` (scalar or (n,)).

        **Arguments:** `play_states`, the plays' states before the first sample.

        **Returns:** a new `GeneralizedPI`.
        """
        pi = PIOperator(self.pi.thresholds, self.pi.weights, play_states, method=self.pi.method)
        return GeneralizedPI(pi, self.amplitudes, self.centres, self.scales, self.offset)

    def normalised(self) -> "GeneralizedPI":
        """The same model (same output for every input) with the first scale s_1 = 1.

        The PI's output unit is free: weights, initial states' images, centres and scales all
        divide by s_1. Two fits of the same data compare parameter by parameter in this form.

        **Returns:** a new `GeneralizedPI`.
        """
        lam = 1.0 / self.scales[0]
        pi = PIOperator(self.pi.thresholds, self.pi.weights * lam, self.pi.initial_states, method=self.pi.method)
        return GeneralizedPI(pi, self.amplitudes, self.centres * lam, self.scales * lam, self.offset)

    def inverse_problem(self) -> str | None:
        """Why the model has no inverse (its PI part has none: `inverse_problem` of the
        operators), or None."""
        return inverse_problem(self.pi.thresholds, self.pi.weights)

    def inverse(self, y: SignalLike, state=None, *, n_iter: int = 80) -> Signal:
        """The input u (T,) whose output follows `y` (T,): u = P⁻¹[g⁻¹(y)], the compensator.

        **Arguments:** `y` (T,), the desired output, inside `output_range()`; `state`, the plays'
        states at the start (default the model's own); `n_iter`, bisection steps of g⁻¹.

        **Returns:** u (T,) with `self(u)` equal to `y` up to rounding. Raises `ValueError` (or an
        `eqx.error_if` error under `jit`) for a target outside the open output range, which no
        input reaches, and when P is not invertible (r_1 ≠ 0 or a cumulative weight ≤ 0).
        """
        y = _checks.finite(_checks.signal(y, "y"), "y").astype(self.centres.dtype)
        lo, hi = self.output_range()
        outside = (y <= lo) | (y >= hi)
        if _checks.is_concrete(y) and _checks.is_concrete(lo):
            if np.any(np.asarray(outside)):
                i = int(np.argmax(np.asarray(outside)))
                raise ValueError(
                    f"the desired output {float(y[i]):.6g} (sample {i}) is outside the range the "
                    f"model saturates at, ({float(lo):.6g}, {float(hi):.6g}): no input reaches it"
                )
        else:
            y = eqx.error_if(y, jnp.any(outside), "the desired output is outside the model's range")
        pi = self.pi if state is None else self.with_state(state).pi
        return pi.inverse()(self.output_inverse(y, n_iter))


# Jitted at module level so that repeat calls with the same shapes reuse one compiled program (an
# eager loop over a fresh closure would compile, and keep, a new one on every call).
@eqx.filter_jit
def _output_inverse(model: GeneralizedPI, y: Array, n_iter: int) -> Array:
    lo_y, hi_y = model.output_range()
    z = (y - model.offset) / (hi_y - model.offset)
    v_k = model.centres + model.scales * jnp.arctanh(z)[..., None]
    bounds = (jnp.min(v_k, axis=-1), jnp.max(v_k, axis=-1))

    def body(_, ab):
        a, b = ab
        mid = 0.5 * (a + b)
        up = model.output_function(mid) < y
        return jnp.where(up, mid, a), jnp.where(up, b, mid)

    a, b = lax.fori_loop(0, n_iter, body, bounds)
    return 0.5 * (a + b)
