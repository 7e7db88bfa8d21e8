"""The exact inverse of PI + creep, sample by sample (docs/fitting.md, compensation).

y[t] = P[u](t) + Σ_k c_k z_k[t] with z_k[t] = a_k z_k[t-1] + (1 - a_k) u[t]. The lags' share of
the present input, Σ c_k (1 - a_k) u[t], joins the identity play's weight (Q = P with w_1 +
Σ c_k (1 - a_k)); what remains, Σ c_k a_k z_k[t-1], is known from the past input. So u[t] =
Q⁻¹[y[t] - Σ c_k a_k z_k[t-1]](t), the inverse's plays and the lags advancing in one scan.
"""

import jax.numpy as jnp
import numpy as np
from jax import lax

from .. import _checks
from .._operators.inverse import inverse_parameters
from .._operators.pi import PIOperator
from .._operators.play import play_step
from .creep import Creep, lag_step


def rest_input(op: PIOperator, gain: float, target) -> float:
    """The input u_0 at which the model at rest gives `target`: op's first output + gain·u_0.

    Used when the lags' steady gain makes the static map non-monotone, so that no closed form
    applies: the map is piecewise linear with corners at x_j ± r_j; of the pieces' crossings the
    one nearest the identity play's state is taken. `ValueError` when none reaches `target`.
    """
    r = np.asarray(op.thresholds, float)
    w = np.asarray(op.weights, float)
    x = np.asarray(op.initial_states, float)
    v = float(target)

    def f(u):
        return float(np.dot(w, np.clip(x, u - r, u + r))) + gain * u

    corners = np.unique(np.concatenate([x - r, x + r]))
    span = 1.0 + float(np.ptp(corners)) + abs(v)
    points = np.concatenate([[corners[0] - span], corners, [corners[-1] + span]])
    values = np.array([f(u) for u in points])
    slopes = np.diff(values) / np.diff(points)
    found = []
    last = len(slopes) - 1
    for i, k in enumerate(slopes):
        # The outer pieces extend without end: only their inner corner bounds them.
        if k != 0:
            u = points[i] + (v - values[i]) / k
            if (i == 0 or u >= points[i]) and (i == last or u <= points[i + 1]):
                found.append(u)
        elif values[i] == v:
            found.append(points[i])
    if not found:
        raise ValueError(
            f"the model at rest cannot reach the first desired output {v:.6g} (its creep's steady "
            "gain makes its static map non-monotone); give the lags' `creep_states`"
        )
    return min(found, key=lambda u: abs(u - x[0]))


def creep_inverse(op: PIOperator, creep: Creep, v, creep_states=None):
    """The input u with op[u] + creep[u] = v (the offset already removed), from the lags'
    `creep_states` (default the creep's own, else at rest at the input the first target needs)."""
    a = creep.decays.astype(v.dtype)
    cw = creep.weights.astype(v.dtype)
    if _checks.is_concrete(op.thresholds) and float(op.thresholds[0]) != 0:
        raise ValueError("the model is not invertible: r_1 must be 0 (the first play the identity)")
    # The present input's share of the lags joins the identity play's weight.
    w = op.weights.at[0].add(jnp.sum(cw * (1.0 - a)))
    ri, wi, xi = inverse_parameters(op.thresholds, w, op.initial_states)
    z0 = creep_states
    if z0 is None:
        z0 = creep.initial_states
    if z0 is None:
        # At rest at the first input u_0 (as the forward model starts): then op[u](0) + Σ c u_0 =
        # v[0], so u_0 is the first sample of the inverse with the lags' whole weight folded in.
        static = op.weights.at[0].add(jnp.sum(cw))
        if _checks.is_concrete(static) and np.any(np.cumsum(np.asarray(static)) <= 0):
            z0 = rest_input(op, float(jnp.sum(cw)), v[0])
        else:
            r0, w0, x0 = inverse_parameters(op.thresholds, static, op.initial_states)
            z0 = jnp.dot(w0, play_step(x0, v[0], r0))
        z0 = jnp.broadcast_to(z0, a.shape)

    def step(carry, vt):
        x, z = carry
        x = play_step(x, vt - jnp.dot(cw * a, z), ri)
        ut = jnp.dot(wi, x)
        return (x, lag_step(z, ut, a)), ut

    _, u = lax.scan(step, (xi, jnp.broadcast_to(jnp.asarray(z0, v.dtype), a.shape)), v)
    return u
