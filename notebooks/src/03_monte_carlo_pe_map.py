# %% [markdown]
# # 03 · A Monte Carlo map of persistent excitation
#
# **The maths.** Notebook 02 checked the paper's chain of reasoning on one input:
#
# $$\underbrace{\min_{t_0}\ \frac{\max_{[t_0,t_0+T_0]} u - \min_{[t_0,t_0+T_0]} u}{2 r_{\max}}}_{\rho(T_0)} \ge 1
#   \quad\Longrightarrow\quad
#   \underbrace{\min_{t_0}\ \lambda_{\min}\Big(\frac{1}{T_0}\int_{t_0}^{t_0+T_0} H_r H_r^\top dt\Big)}_{c_1} > 0
#   \quad\Longrightarrow\quad \hat W \to W .$$
#
# Here we draw thousands of random cases (input family and parameters, thresholds, initial
# states, weights, all from one PRNG key each) and ask how often each link holds. Because $c_1$
# scales with the signal, the map uses the scale-free level
# $\min_{t_0} \lambda_{\min}/\lambda_{\max}$ (0 for a singular window, 1 for a perfectly
# conditioned one) and calls a case PE when it is above the rounding level.
#
# Assumption 1 is sufficient, not necessary. A **sharper condition** follows from counting
# shapes: in a window, a play is *frozen* (constant) or moves; two plays riding the same envelope
# differ by a constant. With $K$ distinct non-constant shapes every play output lies in
# $\mathrm{span}\{1, f_1, \dots, f_K\}$; on sampled data the shapes are also spanned by the $J$
# samples at which some play moves. Two plays are *twins* when $|h_i - h_j|$ is constant on the
# window, and three pairwise twins are always linearly dependent (this happens to thresholds
# closer than the input moves in one sample). So $n$ plays can only be independent when
#
# $$n \le \min(K, J) + 1, \quad \text{no frozen play sits at } 0,
#   \quad \text{and no three plays are pairwise twins.}$$
#
# Failing it proves a window singular; that passing it suffices is what the map tests. The last
# part shards the batch of draws across devices: each draw depends only on its own key, so the
# result is the same on one device or many.

# %%
import functools
import os
import time

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp
import matplotlib.pyplot as plt
import numpy as np

import piest_jax as pj
from piest_jax._families import FAMILIES, draw_case
from piest_jax._montecarlo import (
    draw_family,
    draw_keys,
    draw_statistics,
    make_settings,
    numerical_tolerance,
    pe_map,
    sharper_condition,
)

SMALL = os.environ.get("PIEST_NOTEBOOK_SMALL") == "1"
N_DRAWS = 1400 if SMALL else 14_000  # a multiple of the 7 families

# %% [markdown]
# ## 1. The map
#
# Each draw: $T = 1000$ samples at 2 ms, $n = 5$ plays, windows of 200 samples (0.4 s) starting
# every 20 samples; input amplitudes from well below to well above $r_{\max}$, frequencies from
# slower than a window to much faster. Also computed: the relative weight error of the paper's
# continuous RLS ($P_0 = 10^6 I$) after the whole record, in closed form.

# %%
settings = make_settings(n_samples=1000, n_plays=5, window=200, stride=20)
t_grid = jnp.arange(settings.n_samples) * settings.dt
stats = jax.jit(jax.vmap(functools.partial(draw_statistics, settings=settings)))


def draw_map(key, n_draws):
    """The map family by family: draw i uses fold_in(key, i) and family i mod 7, as in pe_map."""
    index = np.arange(n_draws)
    family = draw_family(index, settings)
    keys = draw_keys(key, 0, n_draws)
    out = {}
    for f in settings.families:
        sel = np.flatnonzero(family == f)
        cases = jax.jit(jax.vmap(lambda k, f=f: draw_case(k, f, t_grid, settings.n_plays)))(keys[sel])
        part = jax.device_get(stats(*cases))
        for name, value in part.items():
            out.setdefault(name, np.zeros((n_draws,) + value.shape[1:], value.dtype))[sel] = value
    out["family"] = family
    return out


start = time.perf_counter()
res = draw_map(jax.random.key(2021), N_DRAWS)
tol = numerical_tolerance(settings.dtype)
a1 = res["rho"] >= 1
pe = res["c1_normalised"] > tol
sharp = res["sharper"]
print(f"{N_DRAWS} draws in {time.perf_counter() - start:.1f} s (including compilation)")

def confusion(cond, name):
    print(f"{'':>24}{'PE':>8}{'not PE':>8}")
    print(f"{name + ' holds':>24}{np.sum(cond & pe):>8}{np.sum(cond & ~pe):>8}")
    print(f"{name + ' fails':>24}{np.sum(~cond & pe):>8}{np.sum(~cond & ~pe):>8}")


confusion(a1, "Assumption 1")
print()
confusion(sharp, "sharper condition")

# %% [markdown]
# Read the tables as: *holds and PE* and *fails and not PE* are agreements. Assumption 1 misses
# many PE cases (it is only sufficient). Cases where Assumption 1 holds but the regressor is not
# PE are worth a look: they are possible on sampled data when a window contains a full sweep but
# two plays still move together (e.g. thresholds closer than one sample's input step) or a play
# frozen at zero. The sharper condition is necessary by construction, so *fails and PE* must be
# empty; how close *holds and not PE* is to empty measures how far from sufficient it is.

# %%
c1n = np.maximum(res["c1_normalised"], 1e-18)
err = np.maximum(res["weight_error"], 1e-18)
fig, (a1x, a2x) = plt.subplots(1, 2, figsize=(11, 4))
for k, fam in enumerate(FAMILIES):
    sel = res["family"] == k
    a1x.loglog(res["rho"][sel], c1n[sel], ".", ms=2, label=fam)
a1x.axvline(1, color="k", lw=0.8, ls=":")
a1x.axhline(tol, color="r", lw=0.8, ls=":")
a1x.set(xlabel="Assumption 1 ratio ρ", ylabel="normalised PE level λmin/λmax",
        title="the map: ρ ≥ 1 (right of the line) vs PE (above red)")
a1x.legend(fontsize=7, markerscale=4)
a2x.loglog(c1n[sharp], err[sharp], ".", ms=2, label="sharper condition holds")
a2x.loglog(c1n[~sharp], err[~sharp], ".", ms=2, label="fails")
a2x.axvline(tol, color="r", lw=0.8, ls=":")
a2x.set(xlabel="normalised PE level", ylabel="RLS relative weight error",
        title="excitation buys convergence")
a2x.legend(fontsize=8, markerscale=4)
fig.tight_layout()

# %%
print(f"{'family':<10}{'draws':>7}{'A1':>7}{'sharper':>9}{'PE':>7}{'median RLS error':>18}")
for k, fam in enumerate(FAMILIES):
    sel = res["family"] == k
    if not sel.any():
        continue
    print(f"{fam:<10}{sel.sum():>7}{a1[sel].mean():>7.2f}{sharp[sel].mean():>9.2f}"
          f"{pe[sel].mean():>7.2f}{np.median(err[sel]):>18.2e}")

# %% [markdown]
# ## 2. The sharper condition on two hand-made cases
#
# A small input ($u = 5\sin 2\pi 5 t$ against $r_{\max} = 20/3$) fails Assumption 1. From a
# relaxed start the third play is frozen *at zero*: the condition fails and the window is
# singular. Give that play a non-zero initial state and it is frozen at a non-zero constant,
# which is independent of the moving plays: the condition holds, and so does PE.

# %%
t = jnp.arange(1001) * 1e-3
u = 5.0 * jnp.sin(2 * jnp.pi * 5.0 * t)
r = jnp.array([0.0, 10 / 3, 20 / 3])
for x0 in (jnp.zeros(3), jnp.array([0.0, 0.0, 1.0])):
    H = pj.play(u, r, x0)
    ok = sharper_condition(H, u, 200, stride=20)
    print(f"x(0) = {np.asarray(x0)}: ρ = {float(pj.assumption1_ratio(u, r[-1], 200)):.2f}, "
          f"sharper condition in every window: {bool(jnp.all(ok))}, "
          f"c1 = {float(pj.pe_level(H, 200, stride=20)):.3g}")

# %% [markdown]
# ## 3. Sharding across devices
#
# `pe_map` (what `piest montecarlo` runs) puts the key axis on a one-axis device mesh
# (`NamedSharding` with `shard_map`), so each device computes its own share of the draws; on a
# machine with several accelerators the same call uses all of them, in chunks that bound memory.
# Draw $i$ always uses `fold_in(key, i)` and family $i \bmod 7$, so the answer cannot depend on
# how the draws are split, over devices or chunks. Below, the first 140 draws through `pe_map`,
# and draws 700 to 839 as a batch of their own, are compared with the map computed above family
# by family. The decisions (PE or not, ρ ≥ 1, the sharper condition, which plays move) must be
# identical; floating-point statistics may differ in the last bits, because XLA vectorises a
# batch of 140 differently from one of 2000.

# %%
print("devices:", jax.devices())
first = pe_map(jax.random.key(2021), 140, settings, quiet=True)
later = pe_map(jax.random.key(2021), 140, settings, start=700, quiet=True)
for name, part, rows in (("draws 0..139", first, slice(0, 140)), ("draws 700..839", later, slice(700, 840))):
    keys = [k for k in part if k not in ("seconds", "thresholds")]
    exact = [k for k in keys if part[k].dtype.kind in "biu"]
    same = all(np.array_equal(part[k], res[k][rows]) for k in exact)
    close = all(np.allclose(part[k], res[k][rows], rtol=1e-9, atol=1e-12) for k in keys if k not in exact)
    decided = np.array_equal(part["c1_normalised"] > tol, pe[rows])
    print(f"{name} through pe_map: {', '.join(exact)} identical: {same}; "
          f"PE decisions identical: {decided}; other statistics within 1e-9: {close}")
