"""The compiled play kernel against the pure-JAX scan, the associative scan and NumPy references.

Outputs: the play bank H agrees with the scan to the last bit, the fused PI output to the rounding of
a different summation order. Gradients (input, thresholds, weights, initial states) agree to a
tolerance scaled by the dtype's epsilon, away from switching instants where the one-sided derivatives
differ; forward mode (jvp, jacfwd, linearize) agrees with the scan, with finite differences and
with reverse mode. Also: jit/vmap/grad composition, the whole-batch kernel call, the threaded batch path, the
fallback when the extension is missing, and the error messages.
"""

import functools
import importlib
import importlib.util
import os
import re
import subprocess
import sys
import textwrap

import hypothesis.extra.numpy as hnp
import hypothesis.strategies as st
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import reference as ref
from hypothesis import given

import piest_jax as pj
from piest_jax._operators.kernel import binding as K

pytestmark = pytest.mark.long

needs_kernel = pytest.mark.skipif(
    not K.available(),
    reason="the compiled play kernel is not built in this installation (no C++ compiler at "
    "install time, or PIEST_KERNEL_BUILD=0)",
)

DTYPES = (np.float32, np.float64)
# (T, n): a single sample and play; T not a multiple of the kernel's blocks of 8 (float32) or 4
# (float64) steps, with n not a multiple of the lanes; more plays than one chunk of vectors.
SHAPES = ((1, 1), (43, 37), (9, 70))
GRAD_T, GRAD_N = 40, 37


@functools.partial(jax.jit, static_argnames="method")
def _bank(u, r, x0, method):
    return pj.play(u, r, x0, method=method)


@functools.partial(jax.jit, static_argnames="method")
def _pi(u, r, x0, w, method):
    return pj.PIOperator(r, w, x0, method=method)(u)


def _bank_loss(u, r, x0, g, method):
    return jnp.sum(g * pj.play(u, r, x0, method=method))


def _pi_loss(u, r, x0, w, g, method):
    return jnp.sum(g * pj.PIOperator(r, w, x0, method=method)(u))


_bank_grad = jax.jit(jax.grad(_bank_loss, argnums=(0, 1, 2)), static_argnames="method")
_pi_grad = jax.jit(jax.grad(_pi_loss, argnums=(0, 1, 2, 3)), static_argnames="method")


def _case(rng, t, n, dtype):
    """A random walk input with random sorted thresholds, states, weights and output cotangent."""
    u = rng.normal(0.0, 1.0, t).cumsum().astype(dtype)
    r = np.sort(rng.uniform(0.0, 2.5, n)).astype(dtype)
    x0 = rng.normal(0.0, 2.0, n).astype(dtype)
    w = rng.normal(0.0, 1.0, n).astype(dtype)
    return u, r, x0, w


def _has_ties(u, r, x0):
    """Whether some step, in the arrays' own precision, has the old state exactly on a bound, or a
    zero threshold makes the two bounds coincide."""
    if np.any(r == 0):
        return True
    x = x0.copy()
    for ut in u:
        lo, hi = ut - r, ut + r
        if np.any(x == lo) or np.any(x == hi):
            return True
        x = np.maximum(lo, np.minimum(hi, x))
    return False


def _sum_tolerance(dtype, terms, scale):
    # Reassociating a sum of `terms` products changes it by at most ~terms * eps * sum(|products|).
    return 4.0 * terms * np.finfo(dtype).eps * scale + np.finfo(dtype).tiny


def _assert_grads_close(got, want, dtype, terms):
    for k, (a, b) in enumerate(zip(got, want)):
        a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
        scale = max(1.0, float(np.max(np.abs(b))))
        np.testing.assert_allclose(a, b, rtol=0, atol=_sum_tolerance(dtype, terms, scale), err_msg=f"argument {k}")


# Forward outputs ------------------------------------------------------------------------------


@st.composite
def _forward_cases(draw):
    dtype = draw(st.sampled_from(DTYPES))
    t, n = draw(st.sampled_from(SHAPES))
    fl = functools.partial(st.floats, allow_subnormal=False, width=np.finfo(dtype).bits)
    u = draw(hnp.arrays(dtype, t, elements=fl(-40, 40)))
    r = draw(hnp.arrays(dtype, n, elements=fl(0, 15), unique=True))  # any order for the bank
    x0 = draw(hnp.arrays(dtype, n, elements=fl(-50, 50)))
    w = draw(hnp.arrays(dtype, n, elements=fl(-5, 5)))
    return u, r, x0, w


@needs_kernel
@given(_forward_cases())
def test_bank_equals_scan_and_associative_to_the_last_bit(case):
    u, r, x0, _ = case
    kernel = np.asarray(_bank(u, r, x0, "kernel"))
    assert kernel.dtype == u.dtype
    np.testing.assert_array_equal(kernel, np.asarray(_bank(u, r, x0, "scan")))
    np.testing.assert_array_equal(kernel, np.asarray(_bank(u, r, x0, "associative")))
    np.testing.assert_allclose(kernel, ref.play(u, r, x0), rtol=2 * np.finfo(u.dtype).eps, atol=0)


@needs_kernel
@given(_forward_cases())
def test_fused_output_equals_scan_up_to_summation_order(case):
    u, r, x0, w = case
    sorted_r = np.sort(r)  # PIOperator needs strictly increasing thresholds
    n = sorted_r.shape[0]
    kernel = np.asarray(_pi(u, sorted_r, x0, w, "kernel"), np.float64)
    scan = np.asarray(_pi(u, sorted_r, x0, w, "scan"), np.float64)
    h = ref.play(u, sorted_r, x0)
    scale = np.abs(h) @ np.abs(w.astype(np.float64))
    bound = _sum_tolerance(u.dtype, n, scale)
    assert np.all(np.abs(kernel - scan) <= bound)
    # And the kernel alone against the float64 reference, to the dtype's rounding.
    rounding = 2 * np.finfo(u.dtype).eps * scale
    assert np.all(np.abs(kernel - ref.pi(u, sorted_r, w, x0)) <= bound + rounding)


@needs_kernel
def test_stop_and_final_states_use_the_kernel_exactly(rng):
    for dtype in DTYPES:
        u, r, x0, w = _case(rng, 50, 9, dtype)
        e_k = pj.stop(u, r, x0, method="kernel")
        np.testing.assert_array_equal(e_k, pj.stop(u, r, x0, method="scan"))
        op_k = pj.PIOperator(r, w, x0, method="kernel")
        op_s = pj.PIOperator(r, w, x0, method="scan")
        np.testing.assert_array_equal(op_k.final_states(u), op_s.final_states(u))
        np.testing.assert_array_equal(op_k.regressor(u), op_s.regressor(u))


# Gradients ------------------------------------------------------------------------------------


@st.composite
def _grad_cases(draw):
    """Continuous random draws (hypothesis picks the seed, dtype and scales), without ties."""
    dtype = draw(st.sampled_from(DTYPES))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    u_scale = draw(st.floats(0.05, 5.0))
    r_scale = draw(st.floats(0.1, 3.0))
    u = (rng.normal(0.0, u_scale, GRAD_T).cumsum() + rng.normal(0.0, 1.0)).astype(dtype)
    r = np.sort(rng.uniform(0.0, r_scale, GRAD_N)).astype(dtype)
    x0 = rng.normal(0.0, 2.0 * r_scale, GRAD_N).astype(dtype)
    w = rng.normal(0.0, 1.0, GRAD_N).astype(dtype)
    g = rng.normal(0.0, 1.0, (GRAD_T, GRAD_N)).astype(dtype)
    return u, r, x0, w, g


@needs_kernel
@given(_grad_cases())
def test_bank_gradients_agree_across_methods(case):
    u, r, x0, _, g = case
    if _has_ties(u, r, x0):
        return  # at a switching instant the methods take different one-sided derivatives
    want = _bank_grad(u, r, x0, g, method="scan")
    # Compiling the associative scan's gradient takes seconds per dtype; one dtype shows that the
    # three paths agree (test_gradients.py checks it against finite differences).
    methods = ("kernel", "associative") if u.dtype == np.float64 else ("kernel",)
    for method in methods:
        got = _bank_grad(u, r, x0, g, method=method)
        assert all(a.dtype == u.dtype for a in got)
        _assert_grads_close(got, want, u.dtype, GRAD_T * GRAD_N)


@needs_kernel
@given(_grad_cases())
def test_fused_gradients_agree_across_methods(case):
    u, r, x0, w, g = case
    if _has_ties(u, r, x0):
        return
    gy = g[:, 0]
    # The associative path of the fused output is the associative bank times w, covered above.
    want = _pi_grad(u, r, x0, w, gy, method="scan")
    got = _pi_grad(u, r, x0, w, gy, method="kernel")
    _assert_grads_close(got, want, u.dtype, GRAD_T * GRAD_N)


@needs_kernel
@pytest.mark.parametrize("dtype", DTYPES)
def test_gradients_at_every_block_boundary(rng, dtype):
    # The kernels take W steps at a time (8 float32, 4 float64) and the leftover steps and t = 0
    # one by one; every split of T around those sizes must give the scan's gradients. The initial
    # states lie above, inside and below the first input's bounds, so that at t = 0 either bound
    # (or none) can be the active one.
    for t in (1, 6, 11):
        u, r, _, w = _case(rng, t, 5, dtype)
        x0 = (u[0] + np.array([3.0, -3.0, 0.0, 2.0, -2.5]) * (r + 0.5)).astype(dtype)
        gy = rng.normal(size=t).astype(dtype)
        g = rng.normal(size=(t, 5)).astype(dtype)
        assert not _has_ties(u, r, x0)
        got = _pi_grad(u, r, x0, w, gy, method="kernel")
        _assert_grads_close(got, _pi_grad(u, r, x0, w, gy, method="scan"), dtype, t * 5)
        got = _bank_grad(u, r, x0, g, method="kernel")
        _assert_grads_close(got, _bank_grad(u, r, x0, g, method="scan"), dtype, t * 5)


@needs_kernel
def _reference_jacobian(args, k, h=1e-6):
    """Central differences (T, size) of the float64 NumPy PI output in argument k of (u, r, x0, w).

    The output is piecewise linear in every argument, so away from switching instants a small
    step is exact up to rounding.
    """
    cols = []
    for i in range(args[k].size):
        plus, minus = [a.copy() for a in args], [a.copy() for a in args]
        plus[k][i] += h
        minus[k][i] -= h
        pi_plus, pi_minus = (ref.pi(a[0], a[1], a[3], a[2]) for a in (plus, minus))
        cols.append((pi_plus - pi_minus) / (2 * h))
    return np.stack(cols, axis=1)


def test_kernel_gradients_match_finite_differences(rng):
    u, r, x0, w = _case(rng, 30, 6, np.float64)
    gy = rng.normal(size=30)
    assert not _has_ties(u, r, x0)
    grads = _pi_grad(u, r, x0, w, gy, method="kernel")
    for k, grad in enumerate(grads):
        fd = gy @ _reference_jacobian([u, r, x0, w], k)
        np.testing.assert_allclose(grad, fd, rtol=1e-6, atol=1e-6, err_msg=f"argument {k}")


@needs_kernel
def test_gradient_at_a_kink_is_the_hold_branch():
    # u climbs exactly onto the upper bound of a play at rest: x_{t-1} = u_t + r. The kernel counts
    # the step as a hold, so d x_t / d u_t = 0 there and the cotangent flows to the initial state.
    u = jnp.array([1.0, 0.0])
    r = jnp.array([1.0])
    x0 = jnp.array([1.0])
    du, dr, dx0 = jax.grad(lambda *a: jnp.sum(K.bank(*a)), argnums=(0, 1, 2))(u, r, x0)
    np.testing.assert_array_equal(du, [0.0, 0.0])
    np.testing.assert_array_equal(dr, [0.0])
    np.testing.assert_array_equal(dx0, [2.0])


@needs_kernel
def test_threshold_gradient_at_zero_is_the_right_derivative(rng):
    # With r = 0 both bounds equal u and the scan's max/min tie splits the derivative; the kernel
    # gives the derivative from the admissible side r > 0, where the play is piecewise linear in r.
    u, r, x0, w = _case(rng, 30, 4, np.float64)
    r[0] = 0.0
    gy = rng.normal(size=30)
    dr = _pi_grad(u, r, x0, w, gy, method="kernel")[1]
    h = 1e-7
    for j in range(4):
        plus = r.copy()
        plus[j] += h
        minus = r.copy()
        minus[j] -= h if j > 0 else 0.0
        fd = gy @ (ref.pi(u, plus, w, x0) - ref.pi(u, minus, w, x0)) / (plus[j] - minus[j])
        np.testing.assert_allclose(dr[j], fd, rtol=1e-6, atol=1e-6)
    # Every other argument's gradient still agrees with the scan.
    scan = _pi_grad(u, r, x0, w, gy, method="scan")
    got = _pi_grad(u, r, x0, w, gy, method="kernel")
    for k in (0, 2, 3):
        np.testing.assert_allclose(got[k], scan[k], rtol=1e-12, atol=1e-11)


# Forward mode ---------------------------------------------------------------------------------


def _pi_tangent(u, r, x0, w, du, dr, dx0, dw, method):
    return jax.jvp(lambda *a: pj.PIOperator(a[1], a[3], a[2], method=method)(a[0]), (u, r, x0, w), (du, dr, dx0, dw))


def _bank_tangent(u, r, x0, du, dr, dx0, method):
    return jax.jvp(lambda *a: pj.play(*a, method=method), (u, r, x0), (du, dr, dx0))


_pi_jvp = jax.jit(_pi_tangent, static_argnames="method")
_bank_jvp = jax.jit(_bank_tangent, static_argnames="method")


@needs_kernel
@given(_grad_cases())
def test_forward_mode_agrees_with_the_scan(case):
    # A tangent in every argument at once: jvp is linear, so this checks each argument's
    # derivative and their sum. The bank's tangents are copies (no sums), equal to the last bit.
    u, r, x0, w, g = case
    if _has_ties(u, r, x0):
        return
    du, dr, dx0, dw = g[:, 0], g[0], g[1], g[2]  # the case's random normals as tangents
    y, dy = _pi_jvp(u, r, x0, w, du, dr, dx0, dw, method="kernel")
    y_s, dy_s = _pi_jvp(u, r, x0, w, du, dr, dx0, dw, method="scan")
    np.testing.assert_array_equal(y, _pi(u, r, x0, w, "kernel"))
    _assert_grads_close([dy], [dy_s], u.dtype, GRAD_N)
    h, dh = _bank_jvp(u, r, x0, du, dr, dx0, method="kernel")
    np.testing.assert_array_equal(h, _bank(u, r, x0, "scan"))
    np.testing.assert_array_equal(dh, _bank_jvp(u, r, x0, du, dr, dx0, method="scan")[1])


@needs_kernel
def test_forward_mode_matches_finite_differences_and_reverse_mode(rng):
    # jacfwd against central differences of the float64 NumPy reference, and against jacrev: the
    # transpose of the tangent is the backward kernel.
    u, r, x0, w = _case(rng, 30, 6, np.float64)
    assert not _has_ties(u, r, x0)
    args = [u, r, x0, w]
    f = lambda *a: pj.PIOperator(a[1], a[3], a[2], method="kernel")(a[0])  # noqa: E731
    for k in range(4):
        jac = np.asarray(jax.jacfwd(f, argnums=k)(*args))
        np.testing.assert_allclose(jac, _reference_jacobian(args, k), rtol=1e-6, atol=1e-6, err_msg=f"argument {k}")
        np.testing.assert_allclose(jac, jax.jacrev(f, argnums=k)(*args), rtol=1e-12, atol=1e-12)


@needs_kernel
def test_forward_mode_at_a_kink_and_a_zero_threshold_follows_the_kernel(rng):
    # The tangent uses the forward pass's branch codes, so at a tie it takes the hold branch and at
    # r = 0 the admissible side r > 0, as the backward kernel does: jacfwd equals jacrev there.
    u, r, x0 = jnp.array([1.0, 0.0]), jnp.array([1.0]), jnp.array([1.0])
    for k in range(3):
        np.testing.assert_array_equal(jax.jacfwd(K.bank, k)(u, r, x0), jax.jacrev(K.bank, k)(u, r, x0))
    u2, r2, x2, _ = _case(rng, 30, 4, np.float64)
    r2[0] = 0.0
    for k in range(3):
        np.testing.assert_array_equal(jax.jacfwd(K.bank, k)(u2, r2, x2), jax.jacrev(K.bank, k)(u2, r2, x2))


@needs_kernel
@pytest.mark.parametrize("dtype", DTYPES)
def test_forward_mode_composes_with_vmap_jit_and_linearize(rng, dtype):
    b = 3
    u = np.stack([_case(rng, 25, 7, dtype)[0] for _ in range(b)])
    _, r, x0, w = _case(rng, 25, 7, dtype)
    r = r + dtype(0.01)  # no zero threshold: the methods' conventions differ there

    def jac_r(method):
        f = lambda v, rr: pj.PIOperator(rr, w, x0, method=method)(v)  # noqa: E731
        return jax.jit(jax.vmap(jax.jacfwd(f, argnums=1), in_axes=(0, None)))(u, r)

    _assert_grads_close([jac_r("kernel")], [jac_r("scan")], dtype, 7)
    # jacfwd of a batched function (the tangents batched over the basis, the primal over signals).
    batched = lambda rr, m: jax.vmap(lambda v: pj.play(v, rr, x0, method=m))(u)  # noqa: E731
    np.testing.assert_array_equal(jax.jacfwd(batched)(r, "kernel"), jax.jacfwd(batched)(r, "scan"))
    # linearize, then the linear map applied to two tangents.
    y, lin = jax.linearize(lambda rr: pj.play(u[0], rr, x0, method="kernel"), r)
    np.testing.assert_array_equal(y, pj.play(u[0], r, x0, method="scan"))
    for t in (np.ones_like(r), np.arange(7, dtype=dtype)):
        np.testing.assert_array_equal(lin(t), jax.jvp(lambda rr: pj.play(u[0], rr, x0, method="scan"), (r,), (t,))[1])


# Composition with jit / vmap / grad ----------------------------------------------------------


@needs_kernel
@pytest.mark.parametrize("dtype", DTYPES)
def test_vmap_of_grad_with_batched_parameters(rng, dtype):
    b = 3
    cases = [_case(rng, 25, 7, dtype) for _ in range(b)]
    u, r, x0, w = (np.stack(a) for a in zip(*cases))
    gy = rng.normal(size=(b, 25)).astype(dtype)

    def batched(method):
        f = jax.grad(functools.partial(_pi_loss, method=method), argnums=(0, 1, 2, 3))
        return jax.jit(jax.vmap(f))(u, r, x0, w, gy)

    want, got = batched("scan"), batched("kernel")
    _assert_grads_close(got, want, dtype, 25 * 7)
    # Each row equals the unbatched kernel gradient to the last bit.
    for i in range(b):
        row = _pi_grad(u[i], r[i], x0[i], w[i], gy[i], method="kernel")
        for a, c in zip(got, row):
            np.testing.assert_array_equal(a[i], c)


@needs_kernel
def test_nested_vmap_and_grad_of_vmap(rng):
    u = rng.normal(size=(2, 3, 20)).cumsum(-1)
    r = np.array([0.05, 0.4, 1.1])
    x0 = np.array([0.2, -0.3, 0.5])
    nested = jax.vmap(jax.vmap(lambda v: pj.play(v, r, x0, method="kernel")))(u)
    np.testing.assert_array_equal(nested, ref_batch(u, r, x0))

    def loss(params, method):
        rr, xx = params
        per = jax.vmap(lambda v: jnp.sum(pj.play(v, rr, xx, method=method) ** 2))(u[0])
        return jnp.sum(per)

    _assert_grads_close(
        jax.jit(jax.grad(loss), static_argnums=1)((r, x0), "kernel"),
        jax.jit(jax.grad(loss), static_argnums=1)((r, x0), "scan"),
        np.float64,
        3 * 20 * 3,
    )


def ref_batch(u, r, x0):
    return np.stack([np.stack([ref.play(v, r, x0) for v in row]) for row in u])


@needs_kernel
def test_vmap_hands_the_whole_batch_to_one_kernel_call(rng):
    u = rng.normal(size=(5, 16))
    r, x0, w = np.array([0.0, 0.5]), np.zeros(2), np.ones(2)
    forward = lambda v: pj.PIOperator(r, w, x0, method="kernel")(v)  # noqa: E731
    backward = jax.grad(lambda v: jnp.sum(forward(v)))
    tangent = lambda v: jax.jvp(forward, (v,), (jnp.ones_like(v),))[1]  # noqa: E731
    for fn, expected in (
        (forward, ["piest_pi_fwd_f64"]),
        (backward, ["piest_pi_fwd_res_f64", "piest_pi_bwd_f64"]),
        (tangent, ["piest_pi_fwd_res_f64"]),
    ):
        text = str(jax.make_jaxpr(jax.vmap(fn))(u))
        calls = [
            re.search(r"result_avals=\(ShapedArray\(([^)]*)\).*?target_name=(\w+)", c, re.S).groups()
            for c in text.split("ffi_call[")[1:]
        ]
        assert [name for _, name in calls] == expected
        assert all(aval == "float64[5,16]" for aval, _ in calls)  # one call for the whole batch
        assert "while[" not in text and "scan[" not in text
    # Forward mode's tangent is a primitive of its own (so that reverse mode can transpose it);
    # it lowers to one tangent-kernel call for the whole batch, and no loop.
    hlo = jax.jit(jax.vmap(tangent)).lower(u).as_text()
    assert hlo.count("piest_pi_tangent_f64") == 1 and "stablehlo.while" not in hlo


@needs_kernel
def test_threaded_batch_equals_serial_rows(rng, monkeypatch):
    # 8 x 400 x 32 lanes is above the kernel's threshold for splitting a batch across threads.
    u = rng.normal(size=(8, 400)).cumsum(-1)
    r = np.linspace(0.0, 3.0, 30)
    x0 = rng.normal(size=30)
    w = rng.normal(size=30)
    f = jax.jit(jax.vmap(lambda v: pj.PIOperator(r, w, x0, method="kernel")(v)))
    threaded = f(u)
    monkeypatch.setenv("PIEST_KERNEL_THREADS", "1")
    serial = f(u)
    np.testing.assert_array_equal(threaded, serial)
    for i in range(u.shape[0]):
        np.testing.assert_array_equal(threaded[i], _pi(u[i], r, x0, w, "kernel"))


# Fallback and errors -------------------------------------------------------------------------


@pytest.fixture
def without_extension(monkeypatch):
    monkeypatch.setattr(K, "_ext", None)
    monkeypatch.setattr(K, "_IMPORT_ERROR", "simulated: no module named _play_kernel")
    K._warn_fallback.cache_clear()
    yield
    K._warn_fallback.cache_clear()


@pytest.mark.parametrize("method", ["kernel", "auto"])
def test_missing_extension_falls_back_to_the_scan_and_warns_once(rng, without_extension, method):
    u, r, x0, w = _case(rng, 20, 4, np.float64)
    assert not K.available()
    with pytest.warns(RuntimeWarning, match="falls back to the pure-JAX scan") as record:
        h = pj.play(u, r, x0, method=method)
        y = pj.PIOperator(r, w, x0, method=method)(u)
        pj.play(u, r, x0, method=method)
    assert len(record) == 1
    assert "simulated: no module named _play_kernel" in str(record[0].message)
    np.testing.assert_array_equal(h, pj.play(u, r, x0, method="scan"))
    np.testing.assert_array_equal(y, pj.PIOperator(r, w, x0, method="scan")(u))


def test_scan_and_associative_never_touch_the_kernel(rng, without_extension):
    import warnings

    u, r, x0, _ = _case(rng, 10, 3, np.float64)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        pj.play(u, r, x0, method="scan")
        pj.play(u, r, x0, method="associative")


def test_unimportable_extension_in_a_fresh_process():
    # The import itself fails (as after an install without a compiler); the package still imports.
    code = textwrap.dedent(
        """
        import sys, warnings
        sys.modules["piest_jax._operators.kernel._play_kernel"] = None
        import numpy as np
        import piest_jax as pj
        from piest_jax._operators.kernel import available
        assert not available()
        with warnings.catch_warnings(record=True) as rec:
            warnings.simplefilter("always")
            a = pj.play(np.arange(6.0), [0.0, 1.0], method="kernel")
            b = pj.play(np.arange(6.0), [0.0, 1.0], method="kernel")
        assert len(rec) == 1 and "falls back" in str(rec[0].message), rec
        assert np.array_equal(a, pj.play(np.arange(6.0), [0.0, 1.0])) and np.array_equal(a, b)
        print("ok")
        """
    )
    env = {**os.environ, "JAX_PLATFORMS": "cpu"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "ok"


@needs_kernel
def test_the_default_method_is_the_kernel_for_float32_and_float64_only(rng):
    # What a user gets without asking: the kernel (one FFI call, no loop) for float32/float64 with
    # constant thresholds; the scan, silently, for another dtype or thresholds that vary in time.
    import warnings

    u, r, x0, w = _case(rng, 12, 3, np.float64)
    for dtype, target in ((np.float64, "piest_pi_fwd_f64"), (np.float32, "piest_pi_fwd_f32")):
        op = pj.PIOperator(r.astype(dtype), w.astype(dtype), x0.astype(dtype))
        text = str(jax.make_jaxpr(op)(u.astype(dtype)))
        assert target in text and "scan[" not in text
        text = str(jax.make_jaxpr(lambda v: pj.play(v, r.astype(dtype), x0.astype(dtype)))(u.astype(dtype)))
        assert "piest_bank_fwd" in text and "scan[" not in text
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        half = pj.play(u.astype(np.float16), r.astype(np.float16), x0.astype(np.float16))
        varying = pj.play(u, np.tile(r, (12, 1)), x0)
    assert half.dtype == np.float16
    np.testing.assert_array_equal(half, pj.play(*(a.astype(np.float16) for a in (u, r, x0)), method="scan"))
    np.testing.assert_array_equal(varying, pj.play(u, np.tile(r, (12, 1)), x0, method="scan"))
    with pytest.raises(ValueError, match="supports float32 and float64, got float16"):
        pj.play(*(a.astype(np.float16) for a in (u, r, x0)), method="kernel")


def test_kernel_refuses_a_non_cpu_backend(monkeypatch):
    monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
    with pytest.raises(ValueError, match="runs on CPU only"):
        K.use_kernel("kernel")
    assert K.use_kernel("auto") is False


@needs_kernel
def test_bad_shapes_and_dtypes_raise():
    u = jnp.zeros(5)
    r = jnp.array([0.0, 1.0])
    with pytest.raises(ValueError, match=r"one signal u of shape \(T,\)"):
        K.bank(jnp.zeros((2, 5)), r, r)
    with pytest.raises(ValueError, match=r"thresholds r of shape \(n,\)"):
        K.bank(u, jnp.zeros(()), jnp.zeros(()))
    with pytest.raises(ValueError, match=r"`x0` of shape \(2,\), got \(3,\)"):
        K.bank(u, r, jnp.zeros(3))
    with pytest.raises(ValueError, match=r"`w` of shape \(2,\), got \(1,\)"):
        K.pi_output(u, r, r, jnp.zeros(1))
    with pytest.raises(ValueError, match="one dtype for all arguments"):
        K.bank(u, r.astype(jnp.float32), r)
    with pytest.raises(ValueError, match="supports float32 and float64, got float16"):
        K.bank(u.astype(jnp.float16), r.astype(jnp.float16), r.astype(jnp.float16))
    # Through the public API the usual validation comes first.
    with pytest.raises(ValueError, match=r"must be one signal of shape \(T,\)"):
        pj.play(jnp.zeros((2, 5)), r, method="kernel")
    with pytest.raises(ValueError, match="unknown play method"):
        pj.PIOperator(r, r, method="numba")


@needs_kernel
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_input_raises_eagerly_under_jit_vmap_and_grad(bad):
    u = np.linspace(-1.0, 1.0, 12)
    u[7] = bad
    r, w = np.array([0.0, 0.5]), np.array([1.0, 2.0])
    op = pj.PIOperator(r, w, method="kernel")
    with pytest.raises(ValueError, match="`u` contains NaN or inf"):
        pj.play(u, r, method="kernel")
    with pytest.raises(ValueError, match="`u` contains NaN or inf"):
        op(u)
    batch = np.stack([np.zeros(12), u])
    for fn in (
        jax.jit(jax.vmap(op)),
        jax.jit(jax.vmap(lambda v: pj.play(v, r, method="kernel"))),
        jax.jit(jax.vmap(jax.grad(lambda v: jnp.sum(op(v))))),
    ):
        with pytest.raises(Exception, match="`u` contains NaN or inf"):
            jax.block_until_ready(fn(batch))
    # A finite batch goes through the same compiled functions.
    np.testing.assert_array_equal(jax.jit(jax.vmap(op))(batch[:1])[0], op(np.zeros(12)))


def _module(name):
    return importlib.import_module(f"{K.__package__}.{name}")


def _built(name) -> bool:
    return importlib.util.find_spec(f"{K.__package__}.{name}") is not None


@needs_kernel
def test_the_avx2_build_runs_where_the_cpu_has_it_and_the_portable_one_elsewhere(monkeypatch):
    portable = _module("_play_kernel")
    assert portable.isa() == ()  # the target's baseline: it runs on every CPU of the architecture
    has_avx2 = K._missing_isa(("avx2", "fma"), portable) == []
    # CPUID (the module) and the OS's list (/proc/cpuinfo, where there is one) agree.
    if os.path.exists("/proc/cpuinfo"):
        assert has_avx2 == (K._missing_isa(("avx2", "fma")) == [])
    assert K.isa() == (("avx2", "fma") if has_avx2 and _built("_play_kernel_avx2") else ())
    # On a CPU without AVX2 the portable build is loaded, not refused.
    monkeypatch.setattr(K, "_missing_isa", lambda required, probe=None: list(required))
    ext, reason = K._load()
    assert ext is portable and reason == ""


@needs_kernel
def test_a_binary_built_for_missing_cpu_features_is_refused(monkeypatch):
    # A portable module built with machine flags (CFLAGS=-march=...) and moved to a CPU without
    # them must not be loaded: here the AVX2 build stands in for it, on a CPU said to lack AVX2.
    if not _built("_play_kernel_avx2"):
        pytest.skip("no AVX2 build here")
    wide = _module("_play_kernel_avx2")
    monkeypatch.setattr(K, "_import", lambda module: (wide, ""))
    monkeypatch.setattr(K, "_missing_isa", lambda required, probe=None: list(required))
    ext, reason = K._load()
    assert ext is None
    assert "compiled for avx2, fma, which this CPU lacks" in reason
    assert "-march" in reason


@needs_kernel
def test_an_unknown_kernel_isa_choice_is_named(monkeypatch):
    monkeypatch.setenv("PIEST_KERNEL_ISA", "avx512")
    ext, reason = K._load()
    assert ext is None
    assert reason == "PIEST_KERNEL_ISA='avx512' is not one of auto, portable"


@needs_kernel
def test_the_portable_build_equals_the_scan_in_a_fresh_process(tmp_path):
    # The portable module (16-byte vectors) against the scan, off the tie set: the bank to the
    # last bit, the fused PI output to rounding, reverse mode (PI output) and forward mode (bank).
    code = textwrap.dedent(
        """
        import jax, jax.numpy as jnp, numpy as np
        jax.config.update("jax_enable_x64", True)
        import piest_jax as pj
        from piest_jax._operators.kernel import isa
        assert isa() == (), isa()
        rng = np.random.default_rng(7)
        for dtype, tol in ((np.float64, 1e-12), (np.float32, 1e-4)):
            for t, n in ((1, 1), (37, 3), (200, 9), (64, 17)):
                u = rng.normal(0.0, 1.0, t).cumsum().astype(dtype)
                r = np.sort(rng.uniform(0.05, 2.5, n)).astype(dtype)
                x0 = rng.normal(0.0, 2.0, n).astype(dtype)
                w = rng.normal(0.0, 1.0, n).astype(dtype)
                hk = pj.play(u, r, x0, method="kernel")
                assert np.array_equal(hk, pj.play(u, r, x0, method="scan")), (dtype, t, n)
                yk = pj.PIOperator(r, w, x0, method="kernel")(u)
                ys = pj.PIOperator(r, w, x0, method="scan")(u)
                np.testing.assert_allclose(yk, ys, rtol=tol, atol=tol)
                def derivatives(m):
                    loss = lambda u, r, x0: jnp.sum(jnp.sin(pj.PIOperator(r, w, x0, method=m)(u)))
                    tangent = jax.jvp(lambda v: pj.play(v, r, x0, method=m), (u,), (np.ones_like(u),))[1]
                    return (*jax.grad(loss, argnums=(0, 1, 2))(u, r, x0), tangent)

                for a, b in zip(derivatives("kernel"), derivatives("scan")):
                    np.testing.assert_allclose(a, b, rtol=tol, atol=tol)
        print("ok")
        """
    )
    env = {**os.environ, "JAX_PLATFORMS": "cpu", "PIEST_KERNEL_ISA": "portable"}
    # Started outside the source tree, so that an installed (not editable) package is the one
    # imported, as in this process, rather than the tree's copy (`python -c` puts the working
    # folder first on the path).
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "ok"


@needs_kernel
def test_the_kernel_is_built_against_the_installed_jaxlib():
    from importlib.metadata import version

    assert K._built_with(K._ext) == version("jaxlib")


@needs_kernel
def test_a_binary_for_another_jaxlib_is_refused(monkeypatch):
    # pip's isolated build can compile against a newer jaxlib than the one installed: such a
    # kernel must not be registered with this XLA runtime.
    monkeypatch.setattr(K, "_installed_jaxlib", lambda: "0.0.1")
    ext, reason = K._load()
    assert ext is None
    assert f"compiled against jaxlib {K._built_with(K._ext)}, but jaxlib 0.0.1 is installed" in reason
    assert "--no-build-isolation" in reason
