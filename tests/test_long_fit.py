"""Long records: the chunked normal equations against references, the chunked fit against the
in-memory (optimistix) fit, and fits at and around every batching and chunking boundary."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.flatten_util import ravel_pytree

import piest_jax as pj
from piest_jax._identification import fit as _fit
from piest_jax._identification import normal_equations as _ne

pytestmark = pytest.mark.long

R_TRUE = np.array([0.0, 0.2, 0.5, 0.8])
W_TRUE = np.array([1.0, 0.5, 0.3, 0.2])


def record(T, noise=0.01, seed=0):
    t = np.arange(T) / 1000.0
    u = np.sin(2 * np.pi * 3 * t) * (1 + 0.5 * np.sin(2 * np.pi * 0.37 * t))
    y = np.asarray(pj.PIOperator(R_TRUE, W_TRUE, u[0])(u))
    return u, y + noise * np.random.default_rng(seed).standard_normal(T)


def problem(T, n_lags=0, fit_states=False, pad=False):
    """Normalised data, a parameter point away from the optimum and the residuals' arguments."""
    u, y = record(T)
    n = 4
    un, yn, mask, s, x0, _ = _fit._prepare(u, y, n, None, None, None)
    # Hold a stretch out and leave the padding in: the mask must reach every sum.
    mask = mask.at[10:30].set(0.0)
    active = jnp.array([1.0, 1.0, 1.0, 0.0]) if pad else None
    z0 = jnp.full(n_lags, un[0]) if n_lags else None
    log_tau0 = jnp.log(jnp.array([30.0, 300.0][:n_lags])) if n_lags else None
    base = jnp.log(jnp.array([10.0, 10.0 * 10**0.5][:n_lags])) if n_lags else None
    r0 = jnp.array([0.0, 0.15, 0.4, 0.7])
    p = _fit._initial_params(r0, un, yn, x0, mask, True, fit_states, None, active, z0, log_tau0, None, base)
    # Move off the least-squares weights so that the residuals are not orthogonal to anything.
    p = jax.tree.map(lambda a: a + 0.05 * jnp.cos(jnp.arange(jnp.size(a)).reshape(a.shape)), p)
    if active is not None:
        p["increments"] = p["increments"] * active[1:]
        p["weights"] = p["weights"] * active
    args = (un, yn, x0, mask, True, None, active, z0, None, base)
    st = _ne.Settings(True, 1e-6, 1e-9, None, active, None, x0, z0, base)
    return p, args, st


@pytest.mark.parametrize("n_lags, fit_states, pad", [(0, False, False), (2, True, False), (0, True, True)])
def test_normal_equations_match_full_jacobian(n_lags, fit_states, pad):
    # T = 700 is no multiple of the chunk (64): the last chunk is part padding.
    p, args, st = problem(700, n_lags, fit_states, pad)
    theta, unravel = ravel_pytree(p)

    def residuals(th):
        return _fit._residuals(unravel(th), args)

    r = np.asarray(residuals(theta))
    J = np.asarray(jax.jacfwd(residuals)(theta))
    un, yn, x0, mask = args[:4]
    data = tuple(_ne.chunked(a, f, 64) for a, f in ((un, un[-1]), (yn, 0.0), (mask, 0.0)))
    JtJ, Jtr, loss, _ = _ne.normal_equations(theta, unravel, data, st)
    np.testing.assert_allclose(JtJ, J.T @ J, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(Jtr, J.T @ r, rtol=1e-10, atol=1e-13)
    np.testing.assert_allclose(loss, r @ r, rtol=1e-12)
    # The Jacobian itself against central finite differences, column by column.
    h = 1e-6
    fd = np.stack(
        [(residuals(theta + h * e) - residuals(theta - h * e)) / (2 * h) for e in np.eye(theta.shape[0])],
        axis=1,
    )
    np.testing.assert_allclose(JtJ, fd.T @ fd, rtol=1e-4, atol=1e-8)


def test_residual_change_matches_direct_computation():
    p, args, st = problem(300)
    theta, unravel = ravel_pytree(p)
    theta_old = theta + 1e-3
    un, yn, x0, mask = args[:4]
    data = tuple(_ne.chunked(a, f, 64) for a, f in ((un, un[-1]), (yn, 0.0), (mask, 0.0)))
    r = np.asarray(_fit._residuals(unravel(theta), args))
    r_old = np.asarray(_fit._residuals(unravel(theta_old), args))
    *_, change = _ne.normal_equations(theta, unravel, data, st, theta_old, False)
    want = np.max(np.abs(r - r_old) / (st.atol + st.rtol * np.abs(r)))
    np.testing.assert_allclose(change, want, rtol=1e-10)


@pytest.fixture
def chunked_fit(monkeypatch):
    """fit_pi forced onto the chunked path, with chunks of 256 samples."""

    def fit(*a, **kw):
        with monkeypatch.context() as m:
            m.setattr(_fit, "LONG_RECORD", 0)
            m.setattr(_ne, "CHUNK", 256)
            return pj.fit_pi(*a, **kw)

    return fit


@pytest.mark.parametrize(
    "options",
    [
        {},
        {"fit_initial_states": True},
        {"n_lags": 2, "dt": 1e-3},
        {"pad_plays": 6},
        {"max_threshold": 0.9, "positive_weights": False},
    ],
    ids=["plain", "states", "creep", "padded", "bounded-signed"],
)
def test_chunked_fit_equals_in_memory_fit(chunked_fit, options):
    u, y = record(1000)
    if "n_lags" in options:
        # A creep the record determines: lags fitted to a record without one wander over flat
        # directions, where the two solvers' step counts (not their answers) may differ.
        y = y + np.asarray(pj.Creep([0.05, 0.5], [0.3, 0.2], 1e-3)(u))
    a = pj.fit_pi(u, y, 4, key=jax.random.key(0), **options)
    b = chunked_fit(u, y, 4, key=jax.random.key(0), **options)
    assert a.result_name == b.result_name == "successful"
    np.testing.assert_allclose(b.rmse, a.rmse, rtol=1e-8)
    np.testing.assert_allclose(b.start_rmse, a.start_rmse, rtol=1e-6)
    np.testing.assert_allclose(b.thresholds, a.thresholds, atol=1e-5)
    np.testing.assert_allclose(b.weights, a.weights, rtol=1e-4)
    np.testing.assert_allclose(b.offset, a.offset, atol=1e-5)
    np.testing.assert_allclose(b.initial_states, a.initial_states, atol=1e-4)
    if a.creep is not None:
        np.testing.assert_allclose(b.creep.time_constants, a.creep.time_constants, rtol=1e-3)


def test_chunked_fit_recovers_truth_and_stops_at_max_steps(chunked_fit):
    u, y = record(3000, noise=0.0)
    f = chunked_fit(u, y, 4, key=jax.random.key(1))
    assert f.result_name == "successful"
    np.testing.assert_allclose(f.thresholds, R_TRUE, atol=1e-6)
    np.testing.assert_allclose(f.weights, W_TRUE, rtol=1e-6)
    assert float(f.rmse) < 1e-9
    g = chunked_fit(u, y, 4, key=jax.random.key(1), max_steps=2)
    assert g.result_name == "nonlinear_max_steps_reached"
    assert int(g.n_steps) == 2


@pytest.mark.parametrize("T", [255, 769])
def test_chunk_boundaries(chunked_fit, T):
    # Lengths at and around multiples of the chunk (the record itself is padded to 512s first).
    u, y = record(T)
    a = pj.fit_pi(u, y, 2, key=jax.random.key(0), n_starts=2)
    b = chunked_fit(u, y, 2, key=jax.random.key(0), n_starts=2)
    np.testing.assert_allclose(b.rmse, a.rmse, rtol=1e-8)
    np.testing.assert_allclose(b.thresholds, a.thresholds, atol=1e-5)


def test_default_batch_sizes_at_boundaries():
    # starts_at_once x T stays near the budget, and never falls to 0 (lax.map's batch size).
    B = _fit.STARTS_BUDGET
    for T in [1, 2, B // 4 - 1, B // 4, B // 4 + 1, B // 3, B // 2, B - 1, B, B + 1, 10**7]:
        k = _fit.default_starts_at_once(T)
        assert k >= 1
        assert k == 1 or k * T <= B


@pytest.mark.parametrize("T", [512, 513, 1025, 2048, 2049])
def test_batched_starts_equal_unbatched(monkeypatch, T):
    # The in-memory solve's batch boundaries, moved down to short records: with a budget of
    # 2048 samples and 3 starts, the padded lengths 512, 1024, 1536, 2048 and 2560 give batches of
    # 3 (all), 2 (a remainder of 1), 1, 1 and 1; every one equals the unbatched solve.
    monkeypatch.setattr(_fit, "STARTS_BUDGET", 2048)
    u, y = record(T)
    kw = dict(key=jax.random.key(0), n_starts=3, max_steps=30)
    a = pj.fit_pi(u, y, 2, **kw)
    b = pj.fit_pi(u, y, 2, starts_at_once=3, **kw)
    np.testing.assert_allclose(a.start_rmse, b.start_rmse, rtol=1e-10)
    np.testing.assert_allclose(a.thresholds, b.thresholds, atol=1e-10)


def test_starts_compared_on_a_stretch_then_refined_on_all(chunked_fit, monkeypatch):
    # A record with more than twice SCOUT fitted samples compares its starts on the first SCOUT
    # of them and refines the best on every sample: the same optimum as solving every start on
    # every sample.
    u, y = record(3000)
    a = chunked_fit(u, y, 4, key=jax.random.key(0))
    monkeypatch.setattr(_ne, "SCOUT", 600)
    b = chunked_fit(u, y, 4, key=jax.random.key(0))
    assert b.result_name == "successful"
    # The same optimum to the solver's tolerance (rtol 1e-6 on every residual's change).
    np.testing.assert_allclose(b.rmse, a.rmse, rtol=1e-6)
    np.testing.assert_allclose(b.thresholds, a.thresholds, atol=1e-4)
    # Every start is scored on all samples; the chosen one is the refined best.
    assert b.start_rmse.shape == (4,)
    assert float(b.rmse) == float(np.min(b.start_rmse))
    assert np.all(np.asarray(b.start_rmse) >= float(a.rmse) * (1 - 1e-6))


def test_long_fit_reports_its_steps(chunked_fit, monkeypatch):
    import io
    import sys

    from piest_jax import _progress

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    bars = []

    def recording_bar(total, **kw):
        bars.append(_progress.bar(total, **kw))
        return bars[-1]

    monkeypatch.setattr(_ne, "_bar", recording_bar)
    monkeypatch.setattr(sys, "stderr", Terminal())
    u, y = record(1000)
    f = chunked_fit(u, y, 4, key=jax.random.key(0))
    # One bar per fit, over the step budget, advanced by the compiled solve to the steps taken.
    assert len(bars) == 1 and bars[0].total == 100
    assert int(f.n_steps) <= bars[0].n <= 100
    assert "fit, steps on 1000 samples" in sys.stderr.getvalue()
    # Not on a terminal: nothing is drawn.
    monkeypatch.setattr(sys, "stderr", io.StringIO())
    chunked_fit(u, y, 4, key=jax.random.key(0))
    assert sys.stderr.getvalue() == ""
