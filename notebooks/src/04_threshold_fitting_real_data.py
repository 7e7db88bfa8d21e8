# %% [markdown]
# # 04 · Fitting a PI model to measured piezo data, choosing its size, and compensating
#
# **The maths.** For a measured record $(u_t, y_t)$ we fit
#
# $$\hat y_t = \sum_{j=1}^n \omega_j H_{r_j}[u](t) + c, \qquad
#   r = (0,\ s_1,\ s_1 + s_2,\ \dots), \quad s_k = \operatorname{softplus}(\theta_k) > 0,$$
#
# so the thresholds stay ordered with $r_1 = 0$ whatever the solver does, and (with
# `positive_weights=True`) $\omega_j = \operatorname{softplus}(\cdot) > 0$, which keeps every
# cumulative weight positive and the model invertible. The residuals $\hat y - y$ are
# differentiated *through the play scan* and minimised by Levenberg–Marquardt (optimistix);
# the play is piecewise linear in $r$, so the Jacobian exists except at switching instants.
# The fit runs in normalised units, using the play's affine equivariance
# $H_r[a + b u] = a + b\,H_{r/b}[u]$ ($b > 0$) to map back exactly.
#
# A play whose threshold exceeds half the input's peak-to-peak range never leaves its flat
# interior (Assumption 1 fails for it), so the data say nothing about that threshold: the fit
# flags such plays. The number of plays is chosen on a **blocked hold-out** (the last part of the
# record, so correlated neighbours never straddle the split) or by BIC,
# $T\ln\mathrm{MSE} + k\ln T$. Finally the fitted model's analytic inverse gives a feedforward
# compensator, $u = P^{-1}[y_d - c]$.
#
# Data: `piezo_chandra2023_1hz.csv` (Chandra et al. 2023, MIT licence; ±150 V, 1 Hz) and the
# two Aye & Ang (2018) micromanipulator records (MIT licence); provenance in
# `piest_jax/data/README.md`.

# %%
import os

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp
import matplotlib.pyplot as plt
import numpy as np

import piest_jax as pj

SMALL = os.environ.get("PIEST_NOTEBOOK_SMALL") == "1"
STEP = 50 if SMALL else 20  # decimation of the 5 kHz record
# Each number of plays is its own compiled fit; records up to 512 samples share one compilation.
CANDIDATES = (2, 4) if SMALL else (1, 2, 3, 4, 6, 8)

# %% [markdown]
# ## 1. The data
#
# The actuator rests until $t \approx 3.26$ s, then follows a 1 Hz sine of ±150 V for about
# 6.7 cycles. We keep the record from 3.2 s on, decimated (1 Hz is slow against the 5 kHz
# sampling rate, and the PI operator is rate independent).

# %%
rec = pj.load_dataset("piezo_chandra2023_1hz")
start = int(np.searchsorted(rec.t, 3.2))
t = rec.t[start::STEP]
u = jnp.asarray(rec.u[start::STEP])
y = jnp.asarray(rec.y[start::STEP])
print(f"{rec.n_samples} samples at {1 / rec.dt:.0f} Hz -> {t.shape[0]} samples at {1 / (STEP * rec.dt):.0f} Hz")

fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 3.6))
a1.plot(t, u / 10, label="u / 10 [V]")
a1.plot(t, y, label="y [µm]")
a1.set(xlabel="t [s]", title="piezo record (Chandra et al. 2023)")
a1.legend(fontsize=8)
a2.plot(u, y, lw=0.8)
a2.set(xlabel="u [V]", ylabel="y [µm]", title="the hysteresis loop")
fig.tight_layout()

# %% [markdown]
# ## 2. Fitting thresholds and weights
#
# `fit_pi` solves several starting threshold grids at once (`vmap`) and keeps the best. The
# baseline is `uniform_pi`: the same number of plays with uniformly spaced thresholds and only
# the weights fitted (a linear least-squares problem).

# %%
n = 4
fit = pj.fit_pi(u, y, n)
base = pj.uniform_pi(u, y, n)
print(f"fitted, n = {n}: RMSE {float(fit.rmse):.4f} µm ({fit.result_name}, {int(fit.n_steps)} steps)")
print(f"uniform thresholds: RMSE {float(base.rmse):.4f} µm")
print("thresholds [V]", np.round(np.asarray(fit.thresholds), 2))
print("weights [µm/V]", np.round(np.asarray(fit.weights), 4), "| offset", round(float(fit.offset), 3))
print("flagged (not excited):", np.asarray(fit.flagged))

y_fit = fit(u)
fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 3.6))
a1.plot(u, y, lw=0.8, label="measured")
a1.plot(u, y_fit, "--", lw=1, label=f"fitted PI, n = {n}")
a1.set(xlabel="u [V]", ylabel="y [µm]", title="data and model")
a1.legend(fontsize=8)
a2.plot(t, y - y_fit, lw=0.8, label="fitted thresholds")
a2.plot(t, y - base(u), lw=0.8, alpha=0.7, label="uniform thresholds")
a2.set(xlabel="t [s]", ylabel="residual [µm]", title="what the model misses")
a2.legend(fontsize=8)
fig.tight_layout()

# %% [markdown]
# The residual is not white: it repeats every cycle. Part of it is the start (the fit assumes
# every play starts relaxed at $u_0$), part of it is what a rate-independent, symmetric PI
# operator cannot represent; notebook 05 is about naming such effects.
#
# ## 3. How many plays?
#
# Each candidate is fitted on the first 70 % of the record and scored on the last 30 %; the
# smallest $n$ within 1 % of the best held-out RMSE wins. BIC on the whole record is shown for
# comparison.

# %%
size = pj.select_plays(u, y, CANDIDATES)
bic = pj.select_plays(u, y, CANDIDATES, criterion="bic")
print("held-out RMSE by n:", {c: round(s, 4) for c, s in zip(size.candidates, size.scores)})
print(f"chosen by hold-out: n = {size.n_plays};  chosen by BIC: n = {bic.n_plays}")

fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 3.4))
a1.plot(size.candidates, size.scores, "o-")
a1.axvline(size.n_plays, color="gray", ls=":")
a1.set(xlabel="number of plays n", ylabel="held-out RMSE [µm]", title="blocked hold-out")
a2.plot(bic.candidates, bic.scores, "s-")
a2.axvline(bic.n_plays, color="gray", ls=":")
a2.set(xlabel="number of plays n", ylabel="BIC", title="Bayesian information criterion")
fig.tight_layout()

# %% [markdown]
# ## 4. A second device: fit on one run, validate on another
#
# The Aye & Ang micromanipulator has an identification record and a separate validation run
# (bursts with pauses). A model that only fits noise would fail on the second.

# %%
ident = pj.load_dataset("piezo_aye2018_identification")
valid = pj.load_dataset("piezo_aye2018_validation")
cut = 500 if SMALL else None
ui, yi = jnp.asarray(ident.u[:cut]), jnp.asarray(ident.y[:cut])
uv, yv = jnp.asarray(valid.u[:cut]), jnp.asarray(valid.y[:cut])
fit_a = pj.fit_pi(ui, yi, 4)
# The validation run starts from its own first sample: relaxed plays at uv[0].
model_v = pj.PIOperator(fit_a.thresholds, fit_a.weights, uv[0])
pred_v = model_v(uv) + fit_a.offset
rms = lambda e: float(jnp.sqrt(jnp.mean(e**2)))  # noqa: E731
print(
    f"identification RMSE {float(fit_a.rmse):.3f}, validation RMSE {rms(pred_v - yv):.3f} "
    f"(output range {float(jnp.ptp(yv)):.1f}, sensor units)"
)

fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 3.6))
a1.plot(ui, yi, lw=0.6)
a1.plot(ui, fit_a(ui), "--", lw=0.8)
a1.set(xlabel="u [V]", ylabel="y", title="identification run")
tv = valid.t[: uv.shape[0]]
a2.plot(tv, yv, lw=0.6, label="measured")
a2.plot(tv, pred_v, "--", lw=0.8, label="model fitted on the other run")
a2.set(xlabel="t [s]", title="validation run")
a2.legend(fontsize=8)
fig.tight_layout()

# %% [markdown]
# ## 5. Inverse compensation
#
# `feedforward(fit, desired)` is $P^{-1}[y_d - c]$. We cannot drive the actuator from a notebook,
# so the stand-in plant is a richer model of it: the piezo fit with the most plays from
# section 3. The compensator is the $n = 4$ fit of section 2; what it misses stays as tracking
# error.
# `evaluate_compensation` compares it with the best straight-line feedforward (gain and offset
# right, hysteresis ignored).

# %%
plant_fit = pj.fit_pi(u, y, max(CANDIDATES))
tt = jnp.arange(2000) * 1e-3
desired = 8.0 * jnp.sin(2 * jnp.pi * 1.0 * tt) + 4.0 * jnp.sin(2 * jnp.pi * 3.0 * tt + 0.5)
comp = pj.evaluate_compensation(plant_fit, fit, desired)
print(
    f"tracking RMSE: inverse-model feedforward {float(comp.rmse_compensated):.3f} µm, "
    f"linear feedforward {float(comp.rmse_linear):.3f} µm"
)

fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 3.6))
a1.plot(tt, comp.desired, "k", lw=1, label="desired")
a1.plot(tt, comp.y_linear, lw=0.8, label="linear feedforward")
a1.plot(tt, comp.y_compensated, "--", lw=0.8, label="inverse PI feedforward")
a1.set(xlabel="t [s]", ylabel="y [µm]", title="tracking on the stand-in plant")
a1.legend(fontsize=8)
a2.plot(comp.desired, comp.y_linear, lw=0.8, label="linear")
a2.plot(comp.desired, comp.y_compensated, lw=0.8, label="compensated")
a2.set(xlabel="desired [µm]", ylabel="achieved [µm]", title="hysteresis left after compensation")
a2.legend(fontsize=8)
fig.tight_layout()

# %% [markdown]
# ## 6. B–H loops: a material that saturates
#
# A PI with positive weights grows without bound; a soft ferrite's flux density does not. The
# shipped MnZn ferrite file holds four closed loops at $H_{\max}$ = 8, 16, 40 and 80 A/m, one
# `segment` each, without a time column (the sample counts). We fit on three loops, taken one
# after another as they were measured (`Record.joined`, `docs/data.md`), and predict the fourth.
# `identify` with its defaults (as `piest fit`) tries a generalized PI, a PI followed by a
# saturating output function, only where such a function of a positive-weight PI's output
# removes at least half its error, and chooses it only where it wins the held-out block with
# every parameter determined. The baseline is the plain 20-play least-squares PI with signed
# weights.

# %%
bh = pj.load_dataset("bh_szewczyk2016_MnZn_ferrite", columns="H,B")
loops = bh.segments()
held = loops[2]  # the 40 A/m loop


def joined(parts):
    u_, y_ = np.concatenate([p.u for p in parts]), np.concatenate([p.y for p in parts])
    labels = np.concatenate([p.segment for p in parts])
    return pj.Record.from_arrays(None, u_, y_, segment=labels).joined()


train = joined([p for p in loops if p is not held])
val = joined([held])
result = pj.identify(train, val)
sel = result.selection
print(f"chosen: {sel.structure} (gate {sel.gpi.gate:.2f}), {sel.gpi.n_plays} plays")
baseline = pj.uniform_pi(train.u, train.y, 20)
pred_pi = np.asarray(pj.PIOperator(baseline.thresholds, baseline.weights, initial_states=val.u[0])(val.u))
pred_pi = pred_pi + float(baseline.offset)
rmse_pi = float(np.sqrt(np.mean((pred_pi - val.y) ** 2)))
print(f"held-out loop: {sel.structure} {float(result.validation.raw.rmse):.4f} T, 20-play PI {rmse_pi:.4f} T")

fig, ax = plt.subplots(figsize=(5.5, 4))
ax.plot(train.u, train.y, color="0.8", lw=0.8, label="the loops fitted on")
ax.plot(val.u, val.y, "k", lw=1.2, label="held-out loop, measured")
ax.plot(val.u, np.asarray(result.validation.raw.prediction), "--", lw=1, label=f"{sel.structure}, predicted")
ax.plot(val.u, pred_pi, ":", lw=1, label="20-play PI, predicted")
ax.set(xlabel="H [A/m]", ylabel="B [T]", title="MnZn ferrite: predicting a loop it did not see")
ax.legend(fontsize=8)
fig.tight_layout()
