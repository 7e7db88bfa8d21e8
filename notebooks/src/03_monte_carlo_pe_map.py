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
import os
import subprocess
import sys
import textwrap

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp
import matplotlib.pyplot as plt
import numpy as np

import piest_jax as pj

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
settings = pj.make_settings(n_samples=1000, n_plays=5, window=200, stride=20)
res = pj.pe_map(jax.random.key(2021), N_DRAWS, settings, quiet=True)
tol = pj.numerical_tolerance(settings.dtype)
a1 = res.rho >= 1
pe = res.c1_normalised > tol
sharp = res.sharper
print(f"{N_DRAWS} draws in {res.seconds:.1f} s (including compilation)")


def confusion(cond, name):
    print(f"{'':>24}{'PE':>8}{'not PE':>8}")
    print(f"{name + ' holds':>24}{np.sum(cond & pe):>8}{np.sum(cond & ~pe):>8}")
    print(f"{name + ' fails':>24}{np.sum(~cond & pe):>8}{np.sum(~cond & ~pe):>8}")


confusion(a1, "Assumption 1")
print()
confusion(sharp, "sharper condition")

# %% [markdown]
# Read the tables as: *holds and PE* and *fails and not PE* are agreements. Assumption 1 misses
# many PE cases (it is only sufficient). The cases where Assumption 1 holds but the regressor is
# not PE contradict Theorem 1 as stated. A typical one is a window on a monotone stretch of u:
# its range exceeds $2r_{\max}$, but every play already rides its envelope, $h_i = u - r_i$, so
# all outputs lie in $\mathrm{span}\{1, u\}$ (the proof needs a reversal followed by a travel of
# $2r_{\max}$ inside the window, which $\rho \ge 1$ does not give). Others come from steps, whose
# jumps move every play in the same sample, and plays whose thresholds are closer than one
# sample's input step. The sharper condition is necessary by construction (proved), so *fails and
# PE* must be empty; how close *holds and not PE* is to empty measures how far from sufficient it
# is, which is only observed.

# %%
c1n = np.maximum(res.c1_normalised, 1e-18)
err = np.maximum(res.weight_error, 1e-18)
fig, (a1x, a2x) = plt.subplots(1, 2, figsize=(11, 4))
for k, fam in enumerate(pj.INPUT_FAMILIES):
    sel = res.family == k
    a1x.loglog(res.rho[sel], c1n[sel], ".", ms=2, label=fam)
a1x.axvline(1, color="k", lw=0.8, ls=":")
a1x.axhline(tol, color="r", lw=0.8, ls=":")
a1x.set(
    xlabel="Assumption 1 ratio ρ",
    ylabel="normalised PE level λmin/λmax",
    title="the map: ρ ≥ 1 (right of the line) vs PE (above red)",
)
a1x.legend(fontsize=7, markerscale=4)
a2x.loglog(c1n[sharp], err[sharp], ".", ms=2, label="sharper condition holds")
a2x.loglog(c1n[~sharp], err[~sharp], ".", ms=2, label="fails")
a2x.axvline(tol, color="r", lw=0.8, ls=":")
a2x.set(xlabel="normalised PE level", ylabel="RLS relative weight error", title="excitation buys convergence")
a2x.legend(fontsize=8, markerscale=4)
fig.tight_layout()

# %%
print(f"{'family':<10}{'draws':>7}{'A1':>7}{'sharper':>9}{'PE':>7}{'median RLS error':>18}")
for k, fam in enumerate(pj.INPUT_FAMILIES):
    sel = res.family == k
    if not sel.any():
        continue
    print(
        f"{fam:<10}{sel.sum():>7}{a1[sel].mean():>7.2f}{sharp[sel].mean():>9.2f}"
        f"{pe[sel].mean():>7.2f}{np.median(err[sel]):>18.2e}"
    )

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
    ok = pj.sharper_condition(H, u, 200, stride=20)
    print(
        f"x(0) = {np.asarray(x0)}: ρ = {float(pj.assumption1_ratio(u, r[-1], 200)):.2f}, "
        f"sharper condition in every window: {bool(jnp.all(ok))}, "
        f"c1 = {float(pj.pe_level(H, 200, stride=20)):.3g}"
    )

# %% [markdown]
# ## 3. Sharding across devices
#
# `pe_map` (what `piest montecarlo` runs) puts the key axis on a one-axis device `Mesh` with a
# `NamedSharding`, and `shard_map` gives each device its own slice of the keys, in chunks that
# bound memory; on a machine with several accelerators, or several hosts joined by
# `jax.distributed`, the same call uses all of them. Here is the sharding it builds over the
# devices this kernel sees:

# %%
sharding = pj.mesh_sharding(jax.devices())
print("devices:", jax.devices())
print("mesh:", dict(sharding.mesh.shape), " partition spec:", sharding.spec)
keys = jax.device_put(pj.draw_keys(jax.random.key(2021), 0, 28), sharding)
print("keys placed on:", sorted(str(d) for d in keys.sharding.device_set))

# %% [markdown]
# A CPU can pretend to be several devices
# (`XLA_FLAGS=--xla_force_host_platform_device_count=4`, read when JAX starts), so the multi-device
# path runs here in a fresh Python process: it maps the first 700 draws over four devices and
# saves them. Draw $i$ always uses `fold_in(key, i)` and family $i \bmod 7$, so the answer cannot
# depend on how the draws are split: the decisions (PE or not, ρ ≥ 1, the sharper condition,
# which plays move) must be identical to the single-device map above, and the floating-point
# statistics may differ only by rounding (a batch can be summed in another order).

# %%
N_SHARDED = 700
script = textwrap.dedent(f"""
    import jax, numpy as np
    jax.config.update("jax_enable_x64", True)
    import piest_jax as pj
    s = pj.make_settings(n_samples=1000, n_plays=5, window=200, stride=20)
    res = pj.pe_map(jax.random.key(2021), {N_SHARDED}, s, chunk=350, quiet=True)
    print("devices:", len(jax.devices()), "mesh:", dict(pj.mesh_sharding(jax.devices()).mesh.shape))
    np.savez("sharded_map.npz", **res.arrays())
""")
env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=4", JAX_PLATFORMS="cpu")
proc = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True)
print(proc.stdout.strip() or proc.stderr[-2000:])
with np.load("sharded_map.npz") as f:
    sharded = dict(f)
os.remove("sharded_map.npz")
rows = slice(0, N_SHARDED)
exact = [k for k in sharded if sharded[k].dtype.kind in "biu"]
same = all(np.array_equal(sharded[k], getattr(res, k)[rows]) for k in exact)
print(f"identical on 4 devices and on 1: {same} ({', '.join(exact)})")
print("PE decisions identical:", np.array_equal(sharded["c1_normalised"] > tol, pe[rows]))
for k in ("rho", "weight_error"):
    ref = getattr(res, k)[rows]
    gap = np.max(np.abs(sharded[k] - ref) / np.maximum(np.abs(ref), 1e-300))
    print(f"{k}: largest relative difference {gap:.1e}")
gap = np.max(np.abs(sharded["c1_normalised"] - res.c1_normalised[rows]))
print(f"c1_normalised (scale free): largest difference {gap:.1e}")
