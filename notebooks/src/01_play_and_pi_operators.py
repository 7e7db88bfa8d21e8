# %% [markdown]
# # 01 · Play, stop and Prandtl–Ishlinskii operators
#
# **The maths.** The *play* (backlash) operator with threshold $r \ge 0$ maps a sampled input
# $u_0, u_1, \dots$ to the state
#
# $$x_t = H_r[u](t) = \max\{u_t - r,\ \min\{u_t + r,\ x_{t-1}\}\}, \qquad x_{-1} = x(0),$$
#
# a clamp of the previous state to the band $[u_t - r, u_t + r]$ (Xu, Zhou & Tan 2021, eqs. 1–2).
# The initial state $x(0)$ need not be zero. The *stop* operator is its dual,
# $E_r[u] = u - H_r[u] \in [-r, r]$. A Prandtl–Ishlinskii (PI) operator is a weighted sum of plays
# (eq. 3),
#
# $$y_t = \sum_{j=1}^n \omega_j H_{r_j}[u](t) = H_r(t)^\top W, \qquad 0 = r_1 < \dots < r_n,$$
#
# linear in the weights $W$ (the regressor $H_r(t)$ is what the estimators of notebook 02 see) and
# non-linear in the thresholds.
#
# Two facts this notebook leans on:
#
# * **Clamps compose into clamps:** $\mathrm{clamp}_{[l_2,h_2]} \circ \mathrm{clamp}_{[l_1,h_1]}
#   = \mathrm{clamp}_{[\mathrm{clamp}_{[l_2,h_2]}(l_1),\ \mathrm{clamp}_{[l_2,h_2]}(h_1)]}$, so the
#   whole play is an associative scan over per-sample clamps, $O(\log T)$ deep instead of $O(T)$.
# * **The inverse of a PI operator is a PI operator.** With cumulative weights
#   $W_i = \omega_1 + \dots + \omega_i > 0$, $r'_i = \sum_{j \le i} \omega_j (r_i - r_j)$,
#   $\omega'_1 = 1/\omega_1$ and $\omega'_i = -\omega_i / (W_i W_{i-1})$.
#
# Everything below runs top to bottom from a clean kernel in well under a minute.

# %%
import os
import time

import jax

jax.config.update("jax_enable_x64", True)  # notebooks are applications: float64 throughout

import jax.numpy as jnp
import matplotlib.pyplot as plt
import numpy as np

import piest_jax as pj

SMALL = os.environ.get("PIEST_NOTEBOOK_SMALL") == "1"  # the test suite runs with small sizes
print("piest_jax", pj.__version__, "| jax", jax.__version__, "| backend", jax.default_backend())

# %% [markdown]
# ## 1. The play operator
#
# The paper's Fig. 2: one input $u = 5\sin(2\pi t)$ through plays of increasing threshold. A
# wider threshold means a wider loop; $r = 0$ is the identity. The plot on the right shows the
# clamp at work: the state stays flat until the input has moved $2r$ away from its last
# reversal.

# %%
t = pj.time_grid(2.0, 1e-3)
u = pj.sine(t, amplitude=5.0, frequency=1.0)
r = jnp.array([0.0, 1.0, 2.0, 3.0])
X = pj.play(u, r)  # (T, n): one column per threshold
print("input", u.shape, "-> play bank", X.shape)

fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 3.6))
for j, rj in enumerate(r):
    a1.plot(u, X[:, j], label=f"r = {float(rj):g}")
    a2.plot(t, X[:, j])
a2.plot(t, u, "k:", lw=0.8, label="u")
a1.set(xlabel="u", ylabel="x = H_r[u]", title="play loops (paper Fig. 2)")
a2.set(xlabel="t [s]", title="play outputs over time")
a1.legend(fontsize=8)
a2.legend(fontsize=8)
fig.tight_layout()

# %% [markdown]
# A plain Python loop is the reference every operator in the package is tested against; here it
# agrees to the last bit (max and min only ever select one of their arguments, so there is no
# rounding to disagree about).


# %%
def play_reference(u, r, x0=0.0):
    x, out = x0, []
    for ut in np.asarray(u):
        x = max(ut - r, min(ut + r, x))
        out.append(x)
    return np.array(out)


ref = play_reference(u, 2.0)
print("max |play - reference| =", float(np.max(np.abs(X[:, 2] - ref))))

# %% [markdown]
# ## 2. The stop operator
#
# $E_r[u] = u - H_r[u]$ is the elastic–plastic element: it follows the input's increments and
# saturates at $\pm r$. A relaxed stop starts from $e_0 = 0$.

# %%
E = pj.stop(u, r)
print("stop outputs lie in [-r, r]:", bool(jnp.all(jnp.abs(E) <= r + 1e-12)))
print("E = u - H with the matching initial state:", float(jnp.max(jnp.abs(E - (u[:, None] - pj.play(u, r, u[0]))))))
fig, ax = plt.subplots(figsize=(5, 3.4))
for j, rj in enumerate(r[1:], start=1):
    ax.plot(u, E[:, j], label=f"r = {float(rj):g}")
ax.set(xlabel="u", ylabel="E_r[u]", title="stop operators")
ax.legend(fontsize=8)
fig.tight_layout()

# %% [markdown]
# ## 3. The PI operator
#
# The paper's simulation setting: thresholds $(0, 10/3, 20/3)$, weights $(1, 3, 5)$,
# $u = 10\sin(2\pi\,5t)$. `PIOperator` is an `equinox.Module`, so it is a pytree: it can be
# passed through `jit`, `vmap` and `grad` like any array. `op(u)` computes the output without
# forming the $(T, n)$ regressor; `op.regressor(u)` forms it, and $y = H W$.

# %%
thresholds = jnp.array([0.0, 10 / 3, 20 / 3])
weights = jnp.array([1.0, 3.0, 5.0])
op = pj.PIOperator(thresholds, weights)
t5 = pj.time_grid(1.0, 1e-3)
u5 = pj.sine(t5, amplitude=10.0, frequency=5.0)
y5 = op(u5)
H5 = op.regressor(u5)
print("n_plays =", op.n_plays, "| H:", H5.shape, "| max |y - H W| =", float(jnp.max(jnp.abs(y5 - H5 @ weights))))

fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 3.6))
a1.plot(u5, y5)
a1.set(xlabel="u", ylabel="y", title="PI loop: y = Σ ω_j H_{r_j}[u]")
for j in range(3):
    a2.plot(t5[:300], H5[:300, j], label=f"H_{{r_{j + 1}}}, r = {float(thresholds[j]):.3g}")
a2.set(xlabel="t [s]", title="the regressor (first 0.3 s)")
a2.legend(fontsize=8)
fig.tight_layout()

# %% [markdown]
# ## 4. Initial states
#
# A play remembers where it was. Starting from non-zero states (eq. 2) changes the first cycle;
# once the input has swept the full range $\pm r_{\max}$ the memory is wiped out and the
# trajectories coincide. `op.final_states(u)` gives the states after a run, so a record can be
# processed in pieces and continued exactly.

# %%
x0 = jnp.array([0.0, 3.0, -5.0])
op_mem = pj.PIOperator(thresholds, weights, initial_states=x0)
y_mem = op_mem(u5)
gap = jnp.abs(y_mem - y5)
wiped = int(jnp.argmax(jnp.cumsum(gap[::-1])[::-1] == 0))
print(f"outputs differ for the first {wiped} samples, identical afterwards")

half = u5.shape[0] // 2
first = pj.PIOperator(thresholds, weights)
second = pj.PIOperator(thresholds, weights, first.final_states(u5[:half]))
y_pieces = jnp.concatenate([first(u5[:half]), second(u5[half:])])
print("run in two pieces == one run:", bool(jnp.array_equal(y_pieces, y5)))

fig, ax = plt.subplots(figsize=(5, 3.4))
ax.plot(u5, y5, label="relaxed start")
ax.plot(u5[: wiped + 1], y_mem[: wiped + 1], "--", label=f"x(0) = {list(np.asarray(x0))}")
ax.set(xlabel="u", ylabel="y", title="memory of the initial states")
ax.legend(fontsize=8)
fig.tight_layout()

# %% [markdown]
# ## 5. The analytic inverse
#
# With $r_1 = 0$ and every cumulative weight positive, `op.inverse()` is again a `PIOperator`
# (closed form in the introduction), with initial states tied to the forward operator's. Feeding
# a desired trajectory $v$ through the inverse and then the forward operator gives $v$ back: this
# is feed-forward hysteresis compensation.

# %%
inv = op.inverse()
print("inverse thresholds", np.round(np.asarray(inv.thresholds), 4))
print("inverse weights   ", np.round(np.asarray(inv.weights), 4))
v = pj.multisine(t5, [40.0, 15.0], [2.0, 7.0])  # a desired output
u_ff = inv(v)
print("max |op(inverse(op)(v)) - v| =", float(jnp.max(jnp.abs(op(u_ff) - v))))

fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 3.6))
a1.plot(t5, v, label="desired v")
a1.plot(t5, op(v / jnp.sum(weights)), ":", label="uncompensated: op(v / Σω)")
a1.plot(t5, op(u_ff), "--", label="compensated: op(inverse(v))")
a1.set(xlabel="t [s]", title="feed-forward compensation")
a1.legend(fontsize=8)
a2.plot(v, u_ff)
a2.set(xlabel="desired v", ylabel="u = inverse(v)", title="the inverse loop")
fig.tight_layout()

# %% [markdown]
# An operator whose loading curve is not increasing has no inverse; the error says which
# condition fails and where.

# %%
try:
    pj.PIOperator(thresholds, jnp.array([1.0, -2.0, 0.5])).inverse()
except ValueError as e:
    print("ValueError:", e)

# %% [markdown]
# ## 6. Sequential scan vs associative scan
#
# `method="scan"` is a `lax.scan` over samples; `method="associative"` uses
# `lax.associative_scan` over the composed clamps. They give identical bits. On a CPU the
# sequential scan is usually faster (the associative form does more work); on an accelerator the
# $O(\log T)$ depth pays off for long records. Batching over many threshold sets or inputs is
# `jax.vmap`.

# %%
T_long = 2_000 if SMALL else 200_000
u_long = pj.multisine(jnp.arange(T_long) * 1e-4, [8.0, 3.0], [3.0, 41.0])
r_bank = jnp.linspace(0.0, 8.0, 16)
outs, times = {}, {}
for method in ("scan", "associative"):
    f = jax.jit(lambda u, m=method: pj.play(u, r_bank, method=m))
    f(u_long).block_until_ready()  # compile once
    best = np.inf
    for _ in range(3):
        start = time.perf_counter()
        outs[method] = f(u_long).block_until_ready()
        best = min(best, time.perf_counter() - start)
    times[method] = best
print("identical outputs:", bool(jnp.array_equal(outs["scan"], outs["associative"])))
for m, s in times.items():
    print(f"{m:>12}: {1e3 * s:7.2f} ms for {T_long} samples x {r_bank.shape[0]} plays")

# %%
# vmap over threshold sets: one PI output per set, checked against a Python loop.
r_sets = jnp.stack([thresholds * s for s in (0.5, 1.0, 1.5)])
y_sets = jax.vmap(lambda rs: pj.PIOperator(rs, weights)(u5))(r_sets)
loop = jnp.stack([pj.PIOperator(rs, weights)(u5) for rs in r_sets])
print("vmap over thresholds:", y_sets.shape, "| equals the loop:", bool(jnp.allclose(y_sets, loop)))

# %% [markdown]
# ## 7. Gradients through the operator
#
# The output is piecewise linear in the thresholds and linear in the weights, so `jax.grad` gives
# exact derivatives away from the switching instants (where the input touches $x \pm r$; there
# JAX splits the derivative evenly between the tied branches). We check the gradient of a
# squared-error loss against central finite differences, then take a few gradient steps to
# recover thresholds from data.

# %%
target = op(u5)


def loss(params):
    rr, ww = params
    return jnp.mean((pj.PIOperator(rr, ww)(u5) - target) ** 2)


p0 = (jnp.array([0.0, 2.5, 7.5]), jnp.array([1.5, 2.5, 5.5]))
g = jax.grad(loss)(p0)
eps = 1e-6
fd_r = [
    (loss((p0[0].at[j].add(eps), p0[1])) - loss((p0[0].at[j].add(-eps), p0[1]))) / (2 * eps)
    for j in (1, 2)  # r_1 = 0 sits on the boundary r >= 0
]
fd_w = [(loss((p0[0], p0[1].at[j].add(eps))) - loss((p0[0], p0[1].at[j].add(-eps)))) / (2 * eps) for j in range(3)]
print("d loss / d r2, r3 : grad", np.round(np.asarray(g[0][1:]), 6), " finite diff", np.round(fd_r, 6))
print("d loss / d w      : grad", np.round(np.asarray(g[1]), 6), " finite diff", np.round(fd_w, 6))

# %%
# The same derivatives drive a least-squares solver. Thresholds stay ordered and non-negative by
# construction: r = (0, e^{z_1}, e^{z_1} + e^{z_2}).
import optimistix as optx


def unpack(z):
    gaps, w = z
    return jnp.concatenate([jnp.zeros(1), jnp.cumsum(jnp.exp(gaps))]), w


def residuals(z, args):
    rr, ww = unpack(z)
    return pj.PIOperator(rr, ww)(u5) - target


z0 = (jnp.log(jnp.array([2.5, 5.0])), p0[1])
sol = optx.least_squares(residuals, optx.LevenbergMarquardt(rtol=1e-10, atol=1e-10), z0, max_steps=100, throw=False)
r_fit, w_fit = unpack(sol.value)
print("solver:", sol.result == optx.RESULTS.successful, "in", int(sol.stats["num_steps"]), "steps")
print("thresholds", np.round(np.asarray(r_fit), 6), "(true", np.round(np.asarray(thresholds), 6), ")")
print("weights   ", np.round(np.asarray(w_fit), 6), "(true", np.asarray(weights), ")")

fig, ax = plt.subplots(figsize=(5, 3.2))
ax.plot(t5, residuals(z0, None), label="initial guess")
ax.plot(t5, residuals(sol.value, None), label="after Levenberg–Marquardt")
ax.set(xlabel="t [s]", ylabel="y_model − y", title="fitting thresholds and weights")
ax.legend(fontsize=8)
fig.tight_layout()
