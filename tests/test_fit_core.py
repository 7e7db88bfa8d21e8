"""The traceable fit core: recovery, agreement with `fit_pi`, `jit`, `vmap` over records, gradients
with respect to the data against finite differences of complete re-fits, and its refusals."""

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
import pytest
from reference import pi as reference_pi  # a plain loop, independent of the library

import piest_jax as pj

pytestmark = pytest.mark.long

R_TRUE = np.array([0.0, 0.5, 1.2])
W_TRUE = np.array([1.0, 0.6, 0.4])
C_TRUE = 0.3
T = 300
KEY = jax.random.key(0)
TIME = np.linspace(0.0, 2.0, T)


def record(amplitude=3.0, phase=0.0, r=R_TRUE, noise_seed=None):
    # A decaying sine with an offset: major and minor loops, and an input that does not start at 0.
    u = 1.0 + amplitude * np.sin(2 * np.pi * 2 * TIME + phase) * (1 - 0.2 * TIME)
    y = reference_pi(u, r, W_TRUE, u[0]) + C_TRUE
    if noise_seed is not None:
        y = y + 0.01 * np.ptp(y) * np.random.default_rng(noise_seed).standard_normal(T)
    return u, y


# One compiled program each for every jitted call of this file with these shapes.
fit_jit = jax.jit(functools.partial(pj.fit_pi_core, n_plays=3, key=KEY))
fit_filter_jit = eqx.filter_jit(functools.partial(pj.fit_pi_core, n_plays=3, key=KEY))
FIELDS = ("thresholds", "weights", "offset", "initial_states", "rmse", "start_rmse")


def assert_same_fit(a, b, rtol, atol):
    for name in FIELDS:
        np.testing.assert_allclose(getattr(a, name), getattr(b, name), rtol=rtol, atol=atol, err_msg=name)


# Two solves of one objective that differ only in rounding (the order of sums, a compiled or an
# op-by-op program) end where the loss stops decreasing in floating point: loss values place an
# optimum only to about sqrt(eps) relative, so a parameter of two such ends may differ by 1e-9 while
# their losses agree to the last digits (measured on an AVX-512 CPU: the same start, compiled and
# op by op, ended 29 and 32 steps in, its thresholds 6.3e-10 apart and its RMSE equal to 3e-17).
SQRT_EPS = float(np.sqrt(np.finfo(np.float64).eps))


def assert_same_optimum(a, b):
    """The same optimum to rounding: the losses agree to 1e-12, the parameters to 2 sqrt(eps)."""
    for name in ("rmse", "start_rmse"):
        np.testing.assert_allclose(getattr(a, name), getattr(b, name), rtol=1e-12, err_msg=name)
    for name in ("thresholds", "weights", "offset", "initial_states"):
        np.testing.assert_allclose(getattr(a, name), getattr(b, name), rtol=2 * SQRT_EPS, atol=1e-12, err_msg=name)


def test_recovers_known_operator():
    u, y = record()
    f = pj.fit_pi_core(u, y, 3, key=KEY)
    assert isinstance(f, pj.PICoreFit)
    assert bool(f.result == optx.RESULTS.successful)
    np.testing.assert_allclose(f.thresholds, R_TRUE, atol=1e-6)
    np.testing.assert_allclose(f.weights, W_TRUE, rtol=1e-5)
    assert abs(float(f.offset) - C_TRUE) < 1e-5
    np.testing.assert_allclose(f.initial_states, u[0])
    assert float(f.rmse) < 1e-8 * np.ptp(y)
    assert not np.any(f.unexcited)
    # The fitted model reproduces the data through the public operator.
    np.testing.assert_allclose(f(u), y, atol=1e-7)
    np.testing.assert_allclose(f.operator()(u) + f.offset, y, atol=1e-7)


@pytest.mark.parametrize(
    "options",
    [{}, {"fit_initial_states": True, "positive_weights": False, "n_starts": 2, "mask": "head"}],
    ids=["default", "fitted_states_signed_masked"],
)
def test_equals_fit_pi(options):
    # fit_pi pads the record with masked samples that move no play: the same objective, solved by
    # the same compiled solve from the same starts, so the same fit (to rounding). The padding
    # changes the order of the sums, so at the default tolerances one solve may stop an iteration
    # before the other (thresholds 3.5e-9 apart on one CPU); solved to 1e-12 both reach the same
    # optimum, to the precision that loss values place one (`assert_same_optimum`).
    u, y = record(noise_seed=7)
    options = dict(options, rtol=1e-12, atol=1e-14)
    if options.get("mask") == "head":
        options["mask"] = (np.arange(T) >= 40).astype(float)  # the first samples only drive the plays
    core = pj.fit_pi_core(u, y, 3, key=KEY, **options)
    host = pj.fit_pi(u, y, 3, key=KEY, covariance=None, **options)
    assert bool(core.result == host.result == optx.RESULTS.successful)
    assert_same_optimum(core, host)
    np.testing.assert_array_equal(core.unexcited, host.flagged)


def test_jit_equals_eager():
    u, y = record(noise_seed=7)
    eager = pj.fit_pi_core(u, y, 3, key=KEY)
    jitted = fit_jit(u, y, mask=np.ones(T))  # the refusals below reuse this compilation
    # Every start reaches the same optimum here, so which of them is best is down to rounding,
    # which differs once the whole fit is compiled as one program: compare the fits, not the steps.
    assert_same_optimum(jitted, eager)


def test_vmap_over_records_equals_separate_fits():
    records = [record(3.0, 0.0, noise_seed=1), record(2.5, 0.4, R_TRUE * 0.8, 2), record(2.0, 1.0, R_TRUE * 0.6, 3)]
    us, ys = (np.stack(a) for a in zip(*records, strict=True))
    batch = jax.vmap(lambda u, y: pj.fit_pi_core(u, y, 3, key=KEY))(us, ys)
    assert batch.thresholds.shape == batch.weights.shape == (3, 3) and batch.rmse.shape == (3,)
    for i, (u, y) in enumerate(records):
        one = pj.fit_pi_core(u, y, 3, key=KEY)
        assert int(batch.n_steps[i]) == int(one.n_steps)
        assert_same_fit(jax.tree.map(lambda a, i=i: a[i], batch), one, rtol=1e-9, atol=1e-12)
    # The records' fits differ as their operators do.
    assert np.ptp(np.asarray(batch.thresholds[:, 2])) > 0.3


def test_gradient_with_respect_to_data_matches_finite_differences():
    # jax.grad of a scalar of the fitted parameters w.r.t. y and u, through implicit differentiation
    # at the optimum, against central differences of complete re-fits along one direction each.
    u, y = record(noise_seed=7)
    coef = jnp.asarray([0.3, -0.7, 1.1, 0.5, -0.2, 0.9, 0.4])

    # The fit is piecewise smooth in the data: a kink lies wherever a fitted threshold crosses a
    # level the input holds, so now and then a difference step straddles one (or, at the smallest
    # steps, meets the solver's stopping error). The median of central differences over steps
    # from 1e-3 to 1e-5 is the derivative of the smooth piece; the solver's tolerances are tight
    # so that the small steps resolve it.
    @jax.jit
    def scalar(u, y):
        f = pj.fit_pi_core(u, y, 3, key=KEY, rtol=1e-10, atol=1e-13, max_steps=400)
        return jnp.dot(coef, jnp.concatenate([f.thresholds[1:], f.weights, f.offset[None], f.rmse[None]]))

    def central(f, d):
        return np.median([(f(h * d) - f(-h * d)) / (2 * h) for h in (1e-3, 5e-4, 2e-4, 1e-4, 5e-5, 2e-5, 1e-5)])

    grad_u, grad_y = jax.grad(scalar, argnums=(0, 1))(u, y)
    d_y = np.random.default_rng(2).standard_normal(T)
    fd_y = central(lambda e: scalar(u, y + e), d_y)
    # u moves along a smooth direction, which keeps every reversal on its sample (a random one
    # would change which sample tops a reversal, a kink at every step).
    d_u = np.sin(2 * np.pi * 0.7 * TIME) + 0.5 * TIME
    fd_u = central(lambda e: scalar(u + e, y), d_u)
    for grad, d, fd in ((grad_y, d_y, fd_y), (grad_u, d_u, fd_u)):
        assert abs(float(fd)) > 1e-2  # a real sensitivity, not a zero gradient
        np.testing.assert_allclose(float(jnp.dot(grad, d)), float(fd), rtol=1e-5)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"n_plays": 0}, "`n_plays` must be a positive whole number"),
        ({"n_starts": 0}, "`n_starts` must be a positive whole number"),
        ({"max_steps": 0}, "`max_steps` must be a positive whole number"),
        ({"rtol": -1.0}, "`rtol` must be a non-negative finite number"),
        ({"solver": "newton"}, "unknown solver"),
        ({"positive_weights": "yes"}, "`positive_weights` must be True or False"),
        ({"n_plays": 200}, "need 401 parameters but the record has only 300 samples"),
        ({"mask": np.ones(T - 1)}, "`mask` has shape"),
        ({"initial_states": np.zeros(2)}, "`initial_states` has 2 entries"),
        ({"y": np.ones(T - 1)}, "`u` has 300 samples but `y` has 299"),
        ({"u": np.ones((2, T))}, "must be one signal of shape"),
    ],
)
def test_static_problems_raise_at_trace_time(change, message):
    u, y = record()
    kw = {"u": u, "y": y, "n_plays": 3, **change}
    with pytest.raises(ValueError, match=message):
        pj.fit_pi_core(**kw)
    data = {name: kw.pop(name) for name in ("u", "y")}
    with pytest.raises(ValueError, match=message):
        jax.jit(lambda u, y: pj.fit_pi_core(u, y, **kw))(**data)


@pytest.mark.parametrize(
    ("u", "y", "mask", "message"),
    [
        (None, "nan", None, "`y` contains NaN or inf"),
        ("inf", None, None, "`u` contains NaN or inf"),
        ("constant", None, None, "the input has zero range"),
        (None, "huge", None, "`y` has values out of the range"),
        (None, None, "few", "fewer samples are fitted"),
    ],
)
def test_problems_in_values_are_refused_not_nan(u, y, mask, message):
    u0, y0 = record()
    u = {None: u0, "inf": np.where(np.arange(T) == 9, np.inf, u0), "constant": np.full(T, 2.0)}[u]
    y = {None: y0, "nan": np.where(np.arange(T) == 5, np.nan, y0), "huge": y0 * 1e160}[y]
    mask = np.ones(T) if mask is None else (np.arange(T) < 6).astype(float)
    # Eager, the values are known at once.
    with pytest.raises(ValueError, match=message):
        pj.fit_pi_core(u, y, 3, key=KEY, mask=mask)
    # Traced, the computation stops with the message (not a fit of NaN): an EquinoxRuntimeError
    # under eqx.filter_jit, and under jax.jit an error that carries the message.
    with pytest.raises(eqx.EquinoxRuntimeError, match=message):
        fit_filter_jit(u, y, mask=mask)
    with pytest.raises(Exception, match=message):
        jax.block_until_ready(fit_jit(u, y, mask=mask))
