# %% [markdown]
# # 05 · Finding what a PI model misses: the discrepancy workflow
#
# **The maths.** A plain PI model $\hat y = P_\theta[u] + c$ fitted to a real actuator leaves a
# residual $e = y - \hat y$. If $e$ were measurement noise alone, its size would match the noise
# floor, which we estimate from the data without any model: a local cubic fitted over 7
# samples (a Savitzky-Golay smoother $S$) follows the signal, loops and reversals included, so
# for white noise of standard deviation $\sigma$ the residual $y - Sy$ has variance
# $\sigma^2(1 - h_0)$, with $h_0$ the smoother's central weight:
#
# $$\hat\sigma = \operatorname{robust\,std}(y - Sy)/\sqrt{1 - h_0} .$$
#
# When $e$ is well above $\hat\sigma$ and structured (it correlates with time, with $\dot u$, it
# concentrates at the start or during holds), some physical effect is missing. The workflow
# tries each candidate effect $k$ (initial state, delay, linear dynamics, rate dependence, creep,
# asymmetry, offset drift, minor loops that change shape with where they sit, saturation), refits,
# and scores it on **held-out blocks**, contiguous blocks
# interleaved with the fitting blocks, so the model runs through them:
#
# $$\text{gain}_k = \mathrm{MSE}_{\text{held-out}}(\text{current}) -
#   \mathrm{MSE}_{\text{held-out}}(\text{current} + k) - \text{penalty}(p_k).$$
#
# The best effect is *named* only when its gain is large against $\hat\sigma^2$ and a real share
# of the remaining error; then the loop repeats on what remains. The result: the effects named,
# in order, and the gap to the noise floor shrinking round by round. Candidates are fitted by
# variable projection (exact least squares for the weights, a grid and a local search for each
# effect's few nonlinear parameters, which avoids the local minima of delays and dynamics);
# the chosen model, and the plain one it is compared with, are then refined jointly by
# optimistix Levenberg-Marquardt, every parameter at once, through the scans.
# `piest diagnose DATA.csv` runs the same workflow and writes a JSON report, a figure and a
# short written report.

# %%
import os

import jax

jax.config.update("jax_enable_x64", True)

import matplotlib.pyplot as plt

import piest_jax as pj

SMALL = os.environ.get("PIEST_NOTEBOOK_SMALL") == "1"
# The full search tries every effect; the small run (for the test suite) tries two.
SEARCH = dict(max_effects=1, candidates=("delay", "linear_dynamics")) if SMALL else {}

# %% [markdown]
# ## 1. A hidden effect, found and named
#
# `pj.hidden_effect_record` draws a synthetic record: a random PI operator, a hidden effect in a
# physical form *different from* the one the diagnosis fits (here the input reaches the actuator
# late, by interpolation), and white plus quantisation noise. The diagnosis does not see the
# truth. `pj.diagnose` returns a `pj.Diagnosis`: the effects named, both models' RMSEs, the
# search's rounds and both models' predictions as fields; its `to_json()` is the report
# `piest diagnose` writes.

# %%
rec, truth = pj.hidden_effect_record(("delay",), key=jax.random.key(1), n_samples=800)
print("hidden:", truth["forms"], f"| true noise std {truth['noise_std']:.4f}")
print(f"noise floor estimated from the data: {pj.noise_std(rec.y):.4f}")

report = pj.diagnose(rec, **SEARCH)
print("named:", report.effects)
print(f"RMSE plain PI {report.baseline_rmse:.4f} -> with named effects {report.final_rmse:.4f}")
ref = report.refinement["model_final"]
print(
    f"joint Levenberg-Marquardt refinement: {ref['result']} after {ref['steps']} steps, "
    f"RMSE {ref['rmse_start']:.4f} -> {ref['rmse']:.4f} (kept: {ref['kept']})"
)
print("parameters:", report.parameters)

# %% [markdown]
# Each round scores every candidate on the held-out blocks; the table is the first round.

# %%
first = report.rounds[0]
print(f"round 1: current held-out RMSE {first['current_heldout_rmse']:.4f}")
for name, c in sorted(first["candidates"].items(), key=lambda kv: -kv[1]["score"]):
    print(f"  {name:<16} held-out RMSE {c['heldout_rmse']:.4f}   score {c['score']:8.2f}")
print("\nwhere the plain model disagrees most:")
for w in [w for w in report.where if w["structured"]][:6]:
    detail = (
        f"r = {w['correlation']:.2f}" if w["kind"] == "correlation" else f"{w['ratio_to_noise']:.1f}x the noise floor"
    )
    print(f"  {w['kind']:<12} {w['name']:<24} {detail}")


# %%
def show(report, title):
    r, base, final = report.record, report.baseline_prediction, report.final_prediction
    names = " + ".join(report.effects) or "no effect"
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 3.6))
    a1.plot(r.t, r.y - base, lw=0.6, label=f"plain PI, RMSE {report.baseline_rmse:.3g}")
    a1.plot(r.t, r.y - final, lw=0.6, label=f"+ {names}, RMSE {report.final_rmse:.3g}")
    sigma = report.noise_std_estimate
    a1.axhspan(-2 * sigma, 2 * sigma, color="0.85", zorder=0, label="±2σ noise floor")
    a1.set(xlabel="t [s]", ylabel="residual y − model", title=f"{title}: residual before and after")
    a1.legend(fontsize=8)
    a2.plot(r.u, r.y, lw=0.5, color="0.6", label="measured")
    a2.plot(r.u, base, lw=0.7, label="plain PI")
    a2.plot(r.u, final, "--", lw=0.7, label=f"+ {names}")
    a2.set(xlabel="u", ylabel="y", title="loops")
    a2.legend(fontsize=8)
    fig.tight_layout()


show(report, "synthetic record, hidden delay")

# %% [markdown]
# ## 2. The Aye & Ang piezo micromanipulator
#
# Real data (MIT licence; provenance in `piest_jax/data/README.md`): the identification record
# and, as a check that the named effects are physics rather than curve fitting, a second run of
# the same device. Only effects that transfer to another run (not the initial state or this
# run's drift) are carried over to it.

# %%
ident = pj.load_dataset("piezo_aye2018_identification")
valid = pj.load_dataset("piezo_aye2018_validation")
if SMALL:
    ident, valid = ident.slice(0, 1000), valid.slice(0, 1000)
real = pj.diagnose(ident, valid, **SEARCH)
v = real.validation
print("named:", real.effects)
print(f"noise floor {real.noise_std_estimate:.3f} (sensor units)")
print(f"{'':<22}{'plain PI':>10}{'with effects':>14}")
print(f"{'identification RMSE':<22}{real.baseline_rmse:>10.3f}{real.final_rmse:>14.3f}")
print(f"{'validation RMSE':<22}{v.baseline_rmse:>10.3f}{v.final_rmse:>14.3f}   (effects used: {v.effects_used})")
# As system identification reports it: only the validation run's offset and initial states
# estimated on it, the model fixed (what no model of the input can know of a run in motion).
print(f"{'  with its IC estimated':<22}{v.baseline_rmse_ic:>10.3f}{v.final_rmse_ic:>14.3f}")
show(real, "Aye identification run")

# %%
vr = v.record
fig, ax = plt.subplots(figsize=(11, 3.4))
ax.plot(vr.t, vr.y - v.baseline_prediction, lw=0.6, label=f"plain PI ({v.baseline_rmse:.3g})")
ax.plot(vr.t, vr.y - v.final_prediction, lw=0.6, label=f"with named effects ({v.final_rmse:.3g})")
ax.set(xlabel="t [s]", ylabel="residual", title="validation run: a model it was not fitted to")
ax.legend(fontsize=8)
fig.tight_layout()
