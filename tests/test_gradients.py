"""Gradients of PI outputs against finite differences of the NumPy reference, and the kink rule.

Away from switching instants (no held state within a margin of a clamp bound) every output is
locally linear in the input, the thresholds, the weights and the initial states, so central
differences of the plain NumPy loop are exact up to rounding and must equal JAX's gradients.

At a switching instant the output has a kink. The sequential scan's convention: `max`/`min` share
the cotangent equally between tied arguments, so at a single tie the gradient is the average of
the two one-sided derivatives. The associative scan agrees away from kinks but not necessarily at
them. A zero threshold sits on the boundary r >= 0 of its domain, so no derivative with respect to
it is claimed (finite differences there would need r < 0).
"""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import reference as ref

import piest_jax as pj

T = 30
N = 5
H = 1e-6
MARGIN = 1e-3


def _case(seed):
    rng = np.random.default_rng(seed)
    u = 3.0 * np.sin(np.linspace(0, 4 * np.pi, T)) + rng.normal(0, 0.8, size=T)
    r = np.r_[0.0, np.sort(rng.uniform(0.2, 2.5, size=N - 1))]
    w = rng.normal(0.5, 1.0, size=N)
    x0 = rng.uniform(-1.0, 1.0, size=N)
    c = rng.normal(size=T)
    return u, r, w, x0, c


def _loss_ref(u, r, w, x0, c):
    return float(c @ ref.pi(u, r, w, x0))


@functools.partial(jax.jit, static_argnames="method")
def _grads(u, r, w, x0, c, method):
    def loss(u, r, w, x0):
        return c @ pj.PIOperator(r, w, x0, method=method)(u)

    return jax.grad(loss, argnums=(0, 1, 2, 3))(u, r, w, x0)


def _central(f, x):
    g = np.zeros_like(x)
    for i in range(x.size):
        e = np.zeros_like(x)
        e[i] = H
        g[i] = (f(x + e) - f(x - e)) / (2 * H)
    return g


def _clear_cases(count):
    """Seeds whose runs keep every held state at least MARGIN away from a clamp bound."""
    out, seed = [], 0
    while len(out) < count:
        case = _case(seed)
        if ref.branches(case[0], case[1], case[3])[1] > MARGIN:
            out.append(case)
        seed += 1
    return out


@pytest.mark.parametrize("method", ["scan", "associative"])
def test_gradients_match_finite_differences_away_from_kinks(method):
    for u, r, w, x0, c in _clear_cases(3):
        gu, gr, gw, gx0 = _grads(u, r, w, x0, c, method)
        fd_u = _central(lambda v: _loss_ref(v, r, w, x0, c), u)
        fd_r = _central(lambda v: _loss_ref(u, np.r_[0.0, v], w, x0, c), r[1:])
        fd_w = _central(lambda v: _loss_ref(u, r, v, x0, c), w)
        fd_x0 = _central(lambda v: _loss_ref(u, r, w, v, c), x0)
        # Locally linear: only rounding (about 1e-16 / H) separates the two.
        for got, want in [(gu, fd_u), (gr[1:], fd_r), (gw, fd_w), (gx0, fd_x0)]:
            np.testing.assert_allclose(got, want, rtol=0, atol=1e-7)
        # The weights' gradient is exactly the regressor contracted with c.
        np.testing.assert_allclose(gw, c @ ref.play(u, r, x0), rtol=0, atol=1e-12)


def test_gradient_flows_through_play_and_stop_directly():
    u, r, _, x0, c = _clear_cases(1)[0]
    C = np.outer(c, np.arange(1.0, N + 1))
    gu_play = jax.jit(jax.grad(lambda v: jnp.sum(C * pj.play(v, r, x0))))(u)
    fd_play = _central(lambda v: float(np.sum(C * ref.play(v, r, x0))), u)
    np.testing.assert_allclose(gu_play, fd_play, rtol=0, atol=1e-7)
    gu_stop = jax.jit(jax.grad(lambda v: jnp.sum(C * pj.stop(v, r, 0.0))))(u)
    fd_stop = _central(lambda v: float(np.sum(C * ref.stop(v, r, 0.0))), u)
    np.testing.assert_allclose(gu_stop, fd_stop, rtol=0, atol=1e-7)


def _one_sided(f, x, i):
    e = np.zeros_like(x)
    e[i] = H
    base = f(x)
    return (f(x + e) - base) / H, (base - f(x - e)) / H


def _default_is_kernel() -> bool:
    """Whether `method="auto"` runs the compiled kernel here (a CPU backend with it built)."""
    from piest_jax._operators.play import resolved

    return resolved("auto") == "kernel"


def test_kink_gradient_is_average_of_one_sided_derivatives():
    # r = 1 from x0 = 0: at t = 2 the input reaches 1, so the held state 0 equals u - r exactly.
    u = np.array([0.0, 0.5, 1.0, 0.5, 2.0, 1.9])
    codes, margin = ref.branches(u, 1.0, 0.0)
    assert margin == 0.0  # this input does sit on a kink
    jac = np.asarray(jax.jacrev(lambda v: pj.play(v, 1.0, 0.0, method="scan"))(u))
    right, left = _one_sided(lambda v: ref.play(v, 1.0, 0.0)[:, 0], u, 2)
    np.testing.assert_allclose(right[2:4], [1.0, 1.0], atol=1e-9)  # pushing up drags the play
    np.testing.assert_allclose(left[2:4], [0.0, 0.0], atol=1e-9)  # pulling down leaves it held
    np.testing.assert_allclose(jac[:, 2], 0.5 * (right + left), rtol=0, atol=1e-9)
    # Away from that instant the Jacobian column is an ordinary derivative.
    r5, l5 = _one_sided(lambda v: ref.play(v, 1.0, 0.0)[:, 0], u, 4)
    np.testing.assert_allclose(r5, l5, atol=1e-9)
    np.testing.assert_allclose(jac[:, 4], r5, rtol=0, atol=1e-9)
    if _default_is_kernel():
        # The default on a CPU is the compiled kernel, which counts the tie as a hold: the
        # one-sided derivative in which the play does not move, in both modes.
        for jacobian in (jax.jacrev, jax.jacfwd):
            kern = np.asarray(jacobian(lambda v: pj.play(v, 1.0, 0.0))(u))
            np.testing.assert_allclose(kern[:, 2], left, rtol=0, atol=1e-9)
            np.testing.assert_allclose(kern[:, 4], r5, rtol=0, atol=1e-9)


def test_initial_state_on_a_bound_gets_the_average():
    # x0 = u_0 + r: raising x0 is clipped (derivative 0), lowering it is held (derivative 1).
    g = jax.grad(lambda x0: pj.play(jnp.array([0.0]), 1.0, x0, method="scan")[0])(1.0)
    right, left = _one_sided(lambda v: ref.play([0.0], 1.0, v[0])[0, 0], np.array([1.0]), 0)
    assert (right, left) == pytest.approx((0.0, 1.0), abs=1e-9)
    assert float(g) == pytest.approx(0.5 * (right + left), abs=1e-9)
    if _default_is_kernel():  # the default on a CPU: the hold branch, in both modes
        for mode in (jax.grad, jax.jacfwd):
            assert float(mode(lambda x0: pj.play(jnp.array([0.0]), 1.0, x0)[0])(1.0)) == pytest.approx(left, abs=1e-9)
