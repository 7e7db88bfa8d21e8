"""The discrete Preisach model and its fit, against plain NumPy references and properties."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import piest_jax as pj
from piest_jax._identification.fit_preisach import normal_equations, penalty_matrix, triangle


def relay_model(u, alphas, betas, weights, offset, start_up):
    """y_t = offset + Σ w_j R_j(t), R_j a relay (+1 when u ≥ α_j, -1 when u ≤ β_j, else held)."""
    state = np.where(start_up, 1.0, -1.0)
    out = np.empty(len(u))
    for t, ut in enumerate(u):
        for j in range(len(alphas)):
            if ut >= alphas[j]:
                state[j] = 1.0
            elif ut <= betas[j]:
                state[j] = -1.0
        out[t] = offset + np.dot(weights, state)
    return out


def reversal_input(rng, n_points, per_leg=12, lo=-1.0, hi=1.0):
    pts = rng.uniform(lo, hi, n_points)
    # Full excursions now and then, so every part of the record exercises the whole triangle.
    pts[::10] = lo
    pts[1::10] = hi
    return np.concatenate([np.linspace(a, b, per_leg, endpoint=False) for a, b in zip(pts[:-1], pts[1:])])


def grid(K, M):
    return np.arange(K) / K, -1.0 + (2.0 * np.arange(M) + 1.0) / M


def smooth_density(K, M):
    r, c = grid(K, M)
    # Zero outside the triangle, where the fit keeps the density at 0.
    return np.exp(-((r[:, None] - 0.3) ** 2 / 0.1 + (c[None, :] - 0.2) ** 2 / 0.3)) * triangle(K, M)


def test_equals_relays_with_memory_for_a_tiny_blur(rng):
    r = np.array([0.0, 0.13, 0.31, 0.52])
    c = np.array([-0.61, -0.2, 0.07, 0.44])
    mu = rng.normal(size=(4, 4))
    # Input values on a grid that avoids every switching value, so there are no ties.
    u = np.round(reversal_input(rng, 60, 9), 2) + 0.005
    model = pj.Preisach(r, c, mu, offset=0.25, blur=1e-6)
    alphas = (c[None, :] + r[:, None]).ravel()
    betas = (c[None, :] - r[:, None]).ravel()
    # Relaxed plays start at u_0: relay (k, m) starts up when u_0 > c_m.
    start_up = np.broadcast_to(u[0] > c[None, :], (4, 4)).ravel()
    ref = relay_model(u, alphas, betas, mu.ravel(), 0.25, start_up)
    np.testing.assert_allclose(np.asarray(model(u)), ref, atol=1e-9)


def test_equal_density_along_centres_is_a_play_up_to_an_affine_map(rng):
    K, M = 5, 12
    r, c = grid(K, M)
    w = rng.uniform(0.5, 2.0, K)
    model = pj.Preisach(r, c, np.repeat(w[:, None], M, axis=1), offset=0.0)
    u = reversal_input(rng, 40)
    H = np.asarray(pj.play(u, r, u[0]))
    # The cells tile [-1, 1] with δ = 1/M, so Σ_m clip((x - c_m)/δ, -1, 1) = M·x there.
    np.testing.assert_allclose(np.asarray(model(u)), M * H @ w, atol=1e-10)


def test_basis_matches_the_call_and_vmap_matches_a_loop(rng):
    K, M = 3, 4
    r, c = grid(K, M)
    model = pj.Preisach(r, c, rng.normal(size=(K, M)), offset=-0.3, initial_states=0.1)
    us = np.stack([reversal_input(rng, 10) for _ in range(3)])
    B = np.asarray(model.basis(us[0]))
    np.testing.assert_allclose(B @ np.asarray(model.density).ravel() - 0.3, np.asarray(model(us[0])), atol=1e-12)
    batched = np.asarray(jax.vmap(model)(jnp.asarray(us)))
    for i in range(3):
        np.testing.assert_allclose(batched[i], np.asarray(model(us[i])), atol=1e-12)


def test_gradients_match_finite_differences(rng):
    K, M = 3, 5
    r, c = grid(K, M)
    model = pj.Preisach(r, c, rng.normal(size=(K, M)), offset=0.2)
    u = jnp.asarray(reversal_input(rng, 12))
    target = jnp.asarray(rng.normal(size=u.shape))

    def loss(density, offset, v):
        m = pj.Preisach(r, c, density, offset)
        return jnp.sum((m(v) - target) ** 2)

    gd, go, gu = jax.grad(loss, argnums=(0, 1, 2))(model.density, model.offset, u)
    eps = 1e-6
    for k, m in [(0, 1), (1, 3), (2, 4)]:
        e = jnp.zeros((K, M)).at[k, m].set(eps)
        fd = (loss(model.density + e, 0.2, u) - loss(model.density - e, 0.2, u)) / (2 * eps)
        np.testing.assert_allclose(gd[k, m], fd, rtol=1e-6, atol=1e-8)
    fd = (loss(model.density, 0.2 + eps, u) - loss(model.density, 0.2 - eps, u)) / (2 * eps)
    np.testing.assert_allclose(go, fd, rtol=1e-6)
    # The input: away from kinks the output is piecewise linear in u, so a small step is exact.
    for t in (5, 40, 77):
        e = jnp.zeros_like(u).at[t].set(1e-7)
        fd = (loss(model.density, 0.2, u + e) - loss(model.density, 0.2, u - e)) / 2e-7
        np.testing.assert_allclose(gu[t], fd, rtol=1e-4, atol=1e-6)


@given(
    seed=st.integers(0, 2**31 - 1),
    early=st.lists(st.floats(-0.6, 0.6), min_size=1, max_size=6),
    early2=st.lists(st.floats(-0.6, 0.6), min_size=1, max_size=6),
    tail=st.lists(st.floats(-0.9, 0.9), min_size=1, max_size=8),
)
def test_wiping_out_and_output_bound(seed, early, early2, tail):
    rng = np.random.default_rng(seed)
    K, M = 4, 6
    r, c = grid(K, M)
    mu = rng.normal(size=(K, M))
    model = pj.Preisach(r, c, mu, offset=0.4)
    # Both start at 0, wander within ±0.6, then go to +0.9 and -0.9 before the same tail.
    a = np.array([0.0, *early, 0.9, -0.9, *tail])
    b = np.array([0.0, *early2, 0.9, -0.9, *tail])
    ya, yb = np.asarray(model(a)), np.asarray(model(b))
    np.testing.assert_allclose(ya[-len(tail) - 1 :], yb[-len(tail) - 1 :], atol=1e-12)
    bound = np.abs(mu).sum() + 0.4
    assert np.all(np.abs(ya) <= bound + 1e-12)


def test_minor_loops_depend_on_where_they_sit():
    """A non-uniform density shapes the same-size minor loop differently at two centres."""
    K, M = 8, 16
    r, c = grid(K, M)
    mu = np.exp(-((c[None, :] - 0.4) ** 2) / 0.02) * np.ones((K, 1))
    model = pj.Preisach(r, c, mu)
    loop = np.array([0.0, 0.2, 0.0, 0.2, 0.0])
    lo = np.asarray(model(np.concatenate([[-1.0], loop - 0.5])))[-3:]
    hi = np.asarray(model(np.concatenate([[-1.0], loop + 0.3])))[-3:]
    # The loop heights (output swings) differ: not congruent.
    assert abs(np.ptp(hi) - np.ptp(lo)) > 0.5 * max(np.ptp(hi), np.ptp(lo))


def test_chunked_normal_equations_equal_the_dense_ones(rng):
    K, M = 3, 5
    r, c = grid(K, M)
    u = reversal_input(rng, 30)
    y = rng.normal(size=u.shape)
    w = (rng.uniform(size=u.shape) > 0.3).astype(float)
    model = pj.Preisach(r, c, np.zeros((K, M)), blur=1.0 / M)
    B = np.concatenate([np.asarray(model.basis(u)), np.ones((len(u), 1))], axis=1)
    G, h, yy, n = normal_equations(
        jnp.asarray(u),
        jnp.asarray(y),
        jnp.asarray(w),
        jnp.asarray(r),
        jnp.asarray(c),
        jnp.full(M, 1.0 / M),
        jnp.full(K, u[0]),
        chunk=37,
        n_blocks=3,
    )
    np.testing.assert_allclose(np.asarray(G).sum(0), (B * w[:, None]).T @ B, atol=1e-9)
    np.testing.assert_allclose(np.asarray(h).sum(0), (B * w[:, None]).T @ y, atol=1e-9)
    np.testing.assert_allclose(float(yy.sum()), np.sum(w * y * y), rtol=1e-12)
    assert float(n.sum()) == w.sum() and np.all(np.asarray(n) > 0)


def test_fit_does_not_depend_on_the_chunk_and_the_kernel_path_equals_the_scan(rng):
    K, M = 4, 6
    r, c = grid(K, M)
    truth = pj.Preisach(r, c, smooth_density(K, M), 0.3)
    u = reversal_input(rng, 60, 11)
    y = np.asarray(truth(u)) + 0.01 * rng.normal(size=u.shape)
    a = pj.fit_preisach(u, y, n_widths=K, n_centres=M, smoothness=1e-3, chunk=17, method="scan")
    b = pj.fit_preisach(u, y, n_widths=K, n_centres=M, smoothness=1e-3, chunk=4096)
    np.testing.assert_allclose(np.asarray(a.model.density), np.asarray(b.model.density), atol=1e-9)
    assert a.rmse == pytest.approx(b.rmse, rel=1e-9)
    auto = pj.Preisach(r, c, smooth_density(K, M), 0.3, method="auto")
    np.testing.assert_array_equal(np.asarray(auto(u)), np.asarray(truth(u)))


def test_penalty_is_zero_on_planes_and_the_triangle_is_the_switching_cells():
    K, M = 4, 5
    r, c = grid(K, M)
    plane = (1.0 + 2.0 * r[:, None] - 3.0 * c[None, :]).ravel()
    D = penalty_matrix(K, M)
    assert abs(plane @ D @ plane) < 1e-10
    bumpy = np.random.default_rng(0).normal(size=K * M)
    assert bumpy @ D @ bumpy > 1.0
    # The triangle: the cells whose blurred relay, driven over [-1, 1] from both ends, still moves.
    u = np.array([-1.0, 1.0, -1.0, 1.0, -1.0])
    moves = np.ptp(np.asarray(pj.Preisach(r, c, np.zeros((K, M))).basis(u))[1:], axis=0) > 0
    np.testing.assert_array_equal(moves.reshape(K, M), triangle(K, M))


def test_fit_recovers_a_known_density_without_noise(rng):
    K, M = 6, 8
    r, c = grid(K, M)
    mu = smooth_density(K, M)
    u = reversal_input(rng, 200, 15)
    y = np.asarray(pj.Preisach(r, c, mu, 0.3)(u))
    fit = pj.fit_preisach(u, y, n_widths=K, n_centres=M, smoothness=0.0)
    assert fit.rmse < 1e-6  # from the normal equations: cancellation limits it near 1e-7
    np.testing.assert_allclose(np.asarray(fit.model.density), mu, atol=1e-6)
    np.testing.assert_allclose(float(fit.model.offset), 0.3, atol=1e-6)
    v = reversal_input(rng, 40, 7)
    np.testing.assert_allclose(np.asarray(fit.model(v)), np.asarray(pj.Preisach(r, c, mu, 0.3)(v)), atol=1e-7)


def test_fit_with_noise_chooses_a_smoothness_and_predicts_near_the_noise(rng):
    K, M = 6, 8
    r, c = grid(K, M)
    truth = pj.Preisach(r, c, smooth_density(K, M), 0.3)
    u = reversal_input(rng, 400, 15)
    sigma = 0.02
    y = np.asarray(truth(u)) + sigma * rng.normal(size=u.shape)
    fit = pj.fit_preisach(u, y, n_widths=K, n_centres=M)
    assert fit.smoothness in fit.candidates
    assert len(fit.held_out_rmse) == len(fit.candidates) and fit.n_blocks == 5
    assert min(fit.held_out_rmse) < 1.15 * sigma
    assert 0.9 * sigma < fit.rmse < 1.05 * sigma
    v = reversal_input(rng, 60, 9)
    err = np.sqrt(np.mean((np.asarray(fit.model(v)) - np.asarray(truth(v))) ** 2))
    assert err < 0.3 * sigma


def test_monotone_fit_has_a_non_negative_density_and_a_monotone_response(rng):
    K, M = 5, 8
    r, c = grid(K, M)
    truth = pj.Preisach(r, c, smooth_density(K, M), 0.0)
    u = reversal_input(rng, 200, 12)
    y = np.asarray(truth(u)) + 0.02 * rng.normal(size=u.shape)
    fit = pj.fit_preisach(u, y, n_widths=K, n_centres=M, smoothness=1e-3, monotone=True)
    assert np.all(np.asarray(fit.model.density) >= 0)
    assert fit.rmse < 0.025
    # For a fixed past, the output rises with the current input.
    ys = [float(fit.model(np.array([0.0, 0.5, -0.2, v]))[-1]) for v in np.linspace(-1, 1, 21)]
    assert np.all(np.diff(ys) >= -1e-9)


def test_fit_is_in_the_data_units_and_honours_the_mask(rng):
    K, M = 4, 6
    r, c = grid(K, M)
    truth = pj.Preisach(r, c, smooth_density(K, M), 0.3)
    u = reversal_input(rng, 150, 10)
    y = np.asarray(truth(u))
    y_bad = y.copy()
    y_bad[200:300] += 5.0
    mask = np.ones_like(u)
    mask[200:300] = 0.0
    fit = pj.fit_preisach(3.0 * u + 2.0, 10.0 * y_bad - 1.0, n_widths=K, n_centres=M, smoothness=0.0, mask=mask)
    v = reversal_input(rng, 30, 6)
    np.testing.assert_allclose(np.asarray(fit.model(3.0 * v + 2.0)), 10.0 * np.asarray(truth(v)) - 1.0, atol=1e-6)


@given(seed=st.integers(0, 2**31 - 1), relaxed=st.booleans())
def test_inverse_of_a_monotone_model_reproduces_the_output(seed, relaxed):
    rng = np.random.default_rng(seed)
    K, M = 4, 6
    r, c = grid(K, M)
    model = pj.Preisach(
        r,
        c,
        rng.uniform(0.0, 1.0, (K, M)) * (rng.uniform(size=(K, M)) > 0.3),
        offset=0.3,
        initial_states=None if relaxed else rng.uniform(-0.5, 0.5, K),
    )
    u = np.clip(np.cumsum(rng.normal(size=80)) * 0.2, -1.0, 1.0)
    y = np.asarray(model(u))
    u_hat = np.asarray(model.inverse(y))
    np.testing.assert_allclose(np.asarray(model(u_hat)), y, atol=1e-10)


def test_inverse_saturates_and_works_under_jit_and_after_a_monotone_fit(rng):
    K, M = 4, 6
    r, c = grid(K, M)
    model = pj.Preisach(r, c, np.ones((K, M)), offset=0.0, initial_states=0.0)
    lo, hi = (float(v) for v in model.input_range())
    assert (lo, hi) == pytest.approx((-1.75, 1.75))
    # The output spans ±24; beyond it the input goes to the end of the range it saturates at.
    u = np.asarray(jax.jit(lambda m, y: m.inverse(y))(model, jnp.array([0.0, 30.0, -30.0, 5.0])))
    assert (u[1], u[2]) == pytest.approx((hi, lo))
    assert float(model(u)[1]) == pytest.approx(24.0)
    assert float(model(u)[2]) == pytest.approx(-24.0)
    np.testing.assert_allclose(float(model(u)[3]), 5.0, atol=1e-10)
    truth = pj.Preisach(r, c, smooth_density(K, M), 0.1)
    v = reversal_input(rng, 80, 10)
    fit = pj.fit_preisach(v, np.asarray(truth(v)), n_widths=K, n_centres=M, monotone=True, smoothness=0.0)
    target = np.asarray(truth(v))[:200]
    np.testing.assert_allclose(np.asarray(fit.model(fit.model.inverse(target))), target, atol=1e-8)


def test_inverse_refuses_a_negative_density():
    model = pj.Preisach([0.0, 0.5], [-0.5, 0.5], [[1.0, -0.1], [0.5, 0.5]])
    with pytest.raises(ValueError, match="cannot be inverted: its density has negative"):
        model.inverse(jnp.zeros(3))


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        (dict(half_widths=[0.2, 0.1]), "half_widths` must be increasing"),
        (dict(half_widths=[-0.1, 0.1]), "non-negative"),
        (dict(centres=[0.0, 0.0, 1.0]), "strictly increasing"),
        (dict(density=np.ones((3, 2))), r"shape \(K, M\) = \(2, 3\)"),
        (dict(density=np.full((2, 3), np.nan)), "`density` contains NaN"),
        (dict(offset=np.ones(2)), "`offset` must be a scalar"),
        (dict(blur=-1.0), "`blur` must be positive"),
        (dict(blur=[0.1, 0.2]), "`blur` must be a scalar or"),
        (dict(initial_states=[0.0, 1.0, 2.0]), "3 entries but there are 2"),
        (dict(method="fast"), "unknown play method"),
    ],
)
def test_model_errors(kwargs, match):
    args = dict(half_widths=[0.0, 0.1], centres=[-0.5, 0.0, 0.5], density=np.ones((2, 3)))
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        pj.Preisach(**args)


def test_traced_bad_values_are_caught():
    def make(c):
        return pj.Preisach([0.0, 0.1], c, jnp.ones((2, 2)), blur=0.1)(jnp.zeros(3))

    with pytest.raises(Exception, match="`centres` must be increasing"):
        jax.jit(make)(jnp.array([0.5, -0.5]))


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        (dict(n_widths=0), "`n_widths` must be an integer >= 1"),
        (dict(n_centres=1), "`n_centres` must be an integer >= 2"),
        (dict(n_widths=30, n_centres=30), "only 100 samples are fitted"),
        (dict(smoothness=-1.0), "`smoothness` must be finite"),
        (dict(n_blocks=1), "needs `n_blocks` >= 2"),
        (dict(mask=np.ones(3)), "`mask` must be"),
        (dict(y=np.ones(99)), "same length"),
        (dict(u=np.ones(100)), "`u` is constant"),
        (dict(u=np.full(100, np.nan)), "`u` contains NaN"),
    ],
)
def test_fit_errors(kwargs, match):
    args = dict(u=np.sin(np.arange(100) / 5.0), y=np.cos(np.arange(100) / 5.0), n_widths=3, n_centres=4)
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        pj.fit_preisach(args.pop("u"), args.pop("y"), **args)


def test_with_initial_states_continues_a_run(rng):
    model = pj.Preisach([0.0, 0.2, 0.5], [-0.5, 0.0, 0.5], rng.normal(size=(3, 3)), offset=0.1)
    u = reversal_input(rng, 12)
    head, tail = u[:50], u[50:]
    cont = model.with_initial_states(model.final_states(head))
    np.testing.assert_allclose(np.asarray(cont(tail)), np.asarray(model(u))[50:], atol=1e-13)
    assert model.with_initial_states(None).initial_states is None
