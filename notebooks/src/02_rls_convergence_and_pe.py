# %% [markdown]
# # 02 · RLS weight estimation, persistent excitation and a convergence certificate
#
# **The maths.** A PI operator is linear in its weights, $y(t) = H_r(t)^\top W$ (eq. 4), so the
# weights can be estimated online. The paper's continuous-time recursive least squares (eqs. 5–6) is
#
# $$\dot{\hat W} = P H_r \frac{y - H_r^\top \hat W}{m^2}, \qquad
#   \dot P = -\frac{P H_r H_r^\top P}{m^2}, \qquad m = 1 + H_r^\top H_r, \quad P(0) = P_0 .$$
#
# For the information matrix $R = P^{-1}$ this is linear, $\dot R = H_r H_r^\top / m^2$, so on
# sampled (zero-order-hold) data one step adds exactly $c_k h_k h_k^\top$ with $c_k = \Delta t / m_k^2$.
# `ContinuousRLS` integrates it exactly, in square-root form, and the noise-free error obeys
#
# $$\|\hat W_k - W\| \le \|\hat W_0 - W\|\,
#   \frac{\lambda_{\max}(P_0^{-1})}{\lambda_{\min}(P_0^{-1}) + \lambda_{\min}\!\big(\textstyle\sum_{i \le k} c_i h_i h_i^\top\big)} .$$
#
# The estimate converges when that accumulated information grows without bound in every
# direction, which is what **persistent excitation** (Definition 1) guarantees:
#
# $$\frac{1}{T_0}\int_{t_0}^{t_0+T_0} H_r H_r^\top\,dt \;\ge\; c_1 I_n \quad \text{for every } t_0 .$$
#
# The paper's **Assumption 1** asks only for the input to sweep at least $2 r_{\max}$ in every
# window, $\max_{[t_0,t_0+T_0]} u - \min_{[t_0,t_0+T_0]} u \ge 2 r_{\max}$, and **Theorem 1**
# shows that this implies persistent excitation (via Lemma 1: PE on a window ⇔ the play outputs
# are linearly independent there). This notebook reproduces the paper's Figs. 5 and 6, measures
# PE levels, turns them into a convergence certificate computed *before* the estimator runs, and
# shows what goes wrong when Assumption 1 fails.

# %%
import os

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp
import matplotlib.pyplot as plt
import numpy as np

import piest_jax as pj

SMALL = os.environ.get("PIEST_NOTEBOOK_SMALL") == "1"  # the test suite runs with small sizes


# %% [markdown]
# ## 1. The paper's Figs. 5 and 6
#
# Thresholds $(0, 10/3, 20/3)$, $\Delta t = 1$ ms, $t \in [0, 1]$ s, $\hat W(0) = 0$. Fig. 5 uses
# $u = 10\sin(2\pi\,5t)$ and $W = (1, 3, 5)$; Fig. 6 adds a 1 Hz component (minor loops) and
# $W = (2, 6, 8)$. The paper does not state $P_0$; with its normalisation each 1 ms sample adds
# only about $10^{-7}$ to the information matrix, so $P_0$ must be large. The right-hand panels
# show how the time to reach 1 % scales with $P_0$ for the paper's normalisation and the more
# common $m^2 = 1 + H_r^\top H_r$. (`piest reproduce all` writes the same figures and a JSON report.)

# %%
from IPython import get_ipython
from IPython.display import display

reports, figures = {}, []
for name in pj.paper.FIGURES:
    rep = pj.paper.reproduce(name)
    reports[name] = rep
    figures.append(pj.paper.figure(rep))
    print(
        f"{name}: {rep['input']:<36} true {np.asarray(rep['weights_true'])}  "
        f"final {np.round(np.asarray(rep['weights_final']), 6)}  "
        f"time to 1 % = {rep['time_to_1pct']:.3f} s  (P0 = {rep['P0']:.0e})"
    )
# The figure helper draws without pyplot (it never touches the backend); activating the inline
# backend registers the hook that displays such figures.
get_ipython().run_line_magic("matplotlib", "inline")
for f in figures:
    display(f)

# %% [markdown]
# ### Estimators side by side
#
# `estimate` runs any estimator over a record. The exact continuous RLS, a discrete RLS with
# forgetting, and the normalised gradient on the Fig. 5 data:

# %%
case = pj.paper.CASES["fig5"]
t = jnp.asarray(case.time())
u = jnp.asarray(case.input())
r = jnp.asarray(pj.paper.THRESHOLDS)
W = jnp.asarray(case.weights)
op = pj.PIOperator(r, W)
H = op.regressor(u)
y = H @ W
estimators = {
    "ContinuousRLS(P0=1e8)": pj.ContinuousRLS(1e8, 1e-3),
    "ForgettingRLS(P0=1e3, λ=0.999)": pj.ForgettingRLS(1e3, 0.999),
    "NormalisedGradient(μ=1)": pj.NormalisedGradient(1.0),
}
fig, ax = plt.subplots(figsize=(7, 3.6))
for label, est in estimators.items():
    res = pj.estimate(est, H, y)
    rel = jnp.linalg.norm(res.weights - W, axis=1) / jnp.linalg.norm(W)
    ax.semilogy(t, jnp.maximum(rel, 1e-16), label=label)
    print(f"{label:<32} final relative error {float(rel[-1]):.2e}")
ax.set(xlabel="t [s]", ylabel="‖Ŵ − W‖ / ‖W‖", title="Fig. 5 data, three estimators")
ax.legend(fontsize=8)
fig.tight_layout()

# %% [markdown]
# ## 2. PE levels and Assumption 1
#
# `windowed_pe_levels(H, window)` is the smallest eigenvalue of each window's Gram matrix, and
# `pe_level` its minimum over windows: the $c_1$ of Definition 1 for $T_0$ = window × Δt.
# `assumption1_ratio(u, r_max, window)` is $\rho(T_0) = \min_{t_0} (\max u - \min u) / 2r_{\max}$,
# so Assumption 1 holds when $\rho \ge 1$. For the Fig. 5 input (5 Hz, period 0.2 s) the worst
# window starts at a zero crossing, and $\rho$ reaches 1 only for windows of about 0.13 s; yet
# $c_1$ is already positive for windows of about 0.04 s. Assumption 1 is sufficient for PE, far
# from necessary (values near $10^{-18}$ are rounding: those windows are singular).

# %%
# Each window length is its own compiled program: the test suite tries fewer.
windows = np.unique(np.round(np.geomspace(5, 400, 8 if SMALL else 30)).astype(int))
c1 = np.array([float(pj.pe_level(H, int(w))) for w in windows])
rho = np.array([float(pj.assumption1_ratio(u, r[-1], int(w))) for w in windows])

fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 3.6))
a1.loglog(windows * 1e-3, np.maximum(c1, 1e-18), "o-")
a1.set(xlabel="window T0 [s]", ylabel="PE level c1", title="Definition 1 on the Fig. 5 regressor")
a2.semilogx(windows * 1e-3, rho, "s-")
a2.axhline(1, color="k", lw=0.8, ls=":")
a2.set(xlabel="window T0 [s]", ylabel="ρ(T0)", title="Assumption 1: ρ ≥ 1")
fig.tight_layout()
tol = 1e-12 * np.max(c1)
print(f"shortest window with c1 > 0: {windows[np.argmax(c1 > tol)]} samples")
print(f"shortest window with ρ >= 1: {windows[np.argmax(rho >= 1)]} samples")

# %% [markdown]
# Lemma 1 says PE on a window is the same as linear independence of the play outputs there.
# `lemma1_check` tests it numerically, and `excited_plays` says which plays move in each window.

# %%
check = pj.lemma1_check(H[:200])
print(
    f"Lemma 1 on the first 0.2 s: rank {int(check.rank)} of 3, "
    f"smallest singular value {float(check.smallest_singular_value):.3g}, "
    f"independent: {bool(check.independent)}"
)
print("plays moving in each 0.2 s window:", np.asarray(pj.excited_plays(H, 200, stride=200)).all(axis=0))

# %% [markdown]
# ## 3. A convergence certificate, before the estimator runs
#
# The bound in the introduction needs only the regressor, i.e. the input and the thresholds:
# not the output, not the weights. `convergence_certificate` returns two versions: `gram_bound`
# from the accumulated information itself, and the cruder `pe_bound` that uses only $c_1$
# (each completed window adds at least $T_0 c_1 / \max m^2$). The estimator's actual error stays
# below both.

# %%
P0 = 1e8
cert = pj.convergence_certificate(H, P0, 1e-3, 200)
res = pj.estimate(pj.ContinuousRLS(P0, 1e-3), H, y)
actual = jnp.linalg.norm(res.weights - W, axis=1) / jnp.linalg.norm(W)
print(f"c1 = {float(cert.c1):.4g}, max m² = {float(cert.max_m2):.4g}")
print("actual <= gram_bound everywhere:", bool(jnp.all(actual <= cert.gram_bound * (1 + 1e-9))))
print("gram_bound <= pe_bound everywhere:", bool(jnp.all(cert.gram_bound <= cert.pe_bound * (1 + 1e-9))))

fig, ax = plt.subplots(figsize=(7, 3.6))
ax.semilogy(t, cert.pe_bound, label="PE bound (c1 only)")
ax.semilogy(t, cert.gram_bound, label="Gram bound")
ax.semilogy(t, jnp.maximum(actual, 1e-16), label="actual ContinuousRLS error")
ax.set(xlabel="t [s]", ylabel="relative weight error", title=f"certificate, P0 = {P0:.0e}·I")
ax.legend(fontsize=8)
fig.tight_layout()

# %% [markdown]
# ## 4. When Assumption 1 fails
#
# Shrink the input to $u = 5\sin(2\pi\,5t)$: it now sweeps 10 < $2 r_{\max}$ = 13.3. The third
# play ($r_3 = 20/3$) never leaves its flat interior: from a relaxed start its output is zero for
# ever, its column of $H$ vanishes, PE fails with $c_1 = 0$, and nothing in the data can say what
# $\omega_3$ is. The estimator fits the output perfectly (the prediction error still goes to
# zero) while $\hat\omega_3$ stays where it started. Identifiability, not fit quality, is what PE
# buys.

# %%
u_small = 5.0 * jnp.sin(2 * jnp.pi * 5.0 * t)
H_small = op.regressor(u_small)
y_small = H_small @ W
print("ρ(0.2 s) =", round(float(pj.assumption1_ratio(u_small, r[-1], 200)), 3))
print("c1       =", float(pj.pe_level(H_small, 200)))
check = pj.lemma1_check(H_small[:200])
print(f"Lemma 1  : rank {int(check.rank)} of 3, independent: {bool(check.independent)}")
print("plays moving in each 0.2 s window:", np.asarray(pj.excited_plays(H_small, 200, stride=200)).all(axis=0))
res_small = pj.estimate(pj.ContinuousRLS(P0, 1e-3), H_small, y_small)
print("final weights", np.round(np.asarray(res_small.weights[-1]), 4), "true", np.asarray(W))
print("final |prediction error| =", float(jnp.abs(res_small.error[-1])))

fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 3.6))
for j in range(3):
    a1.plot(t, res_small.weights[:, j], label=f"ω̂{j + 1} (true {float(W[j]):g})")
a1.set(xlabel="t [s]", title="u = 5 sin(2π5t): ω3 is not identifiable")
a1.legend(fontsize=8)
a2.semilogy(t, jnp.maximum(jnp.abs(res_small.error), 1e-16))
a2.set(xlabel="t [s]", ylabel="|prediction error|", title="…while the output is fitted")
fig.tight_layout()

# %% [markdown]
# Assumption 1 is sufficient, not necessary. A play with non-zero initial state that never moves
# contributes a *constant* column, which is still independent of the oscillating ones, so the
# regressor can be PE even though Assumption 1 fails; and an input that sweeps the full range in
# only some windows gives PE only over the longer windows that contain such a sweep. Notebook 03
# maps out where PE actually holds.

# %%
op_mem = pj.PIOperator(r, W, initial_states=jnp.array([0.0, 0.0, 1.0]))
H_mem = op_mem.regressor(u_small)
print(
    "with x3(0) = 1: ρ =",
    round(float(pj.assumption1_ratio(u_small, r[-1], 200)), 3),
    "but c1 =",
    f"{float(pj.pe_level(H_mem, 200)):.3g}",
    "| Lemma 1 independent:",
    bool(pj.lemma1_check(H_mem[:200]).independent),
)
