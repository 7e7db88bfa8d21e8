"""Model size and inverse compensation on synthetic plants.

1. Plays needed: a plant with three plays whose thresholds are off any uniform grid, identified from
   a noisy record (noise 0.5 % of the output range). RMSE on a separate validation input for the
   uniform grid (weights by least squares) against the fitted thresholds, for growing n.
2. Compensation: the fitted model's inverse drives (a) the plant itself and (b) a plant with model
   error (an output nonlinearity and a first-order lag the PI class lacks, identified with the
   same PI model class). Tracking RMSE against the best linear feedforward.

Writes experiments/results/fit_synthetic.json and experiments/results/fit_synthetic.png.
Run: python experiments/fit_synthetic.py
"""

from pathlib import Path

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

import piest_jax as pj  # noqa: E402

OUT = Path(__file__).parent / "results"
R = np.array([0.0, 0.37, 1.13])
W = np.array([1.0, 0.8, 0.6])
NOISE = 0.005


def rmse(a, b):
    return float(np.sqrt(np.mean((np.asarray(a) - np.asarray(b)) ** 2)))


def lag(y, alpha):
    """First-order lag z_t = z_{t-1} + alpha (y_t - z_{t-1}), z_0 = y_0."""
    z = np.empty_like(y)
    z[0] = y[0]
    for t in range(1, len(y)):
        z[t] = z[t - 1] + alpha * (y[t] - z[t - 1])
    return z


def main():
    OUT.mkdir(parents=True, exist_ok=True)
    t = np.linspace(0, 6, 1200)
    u_id = 2.0 * np.sin(2 * np.pi * t) * (1 - 0.12 * t)
    u_val = 1.6 * np.sin(2 * np.pi * 0.7 * t) + 0.5 * np.sin(2 * np.pi * 2.3 * t)
    plant = pj.PIOperator(R, W, 0.0)
    y_id = np.asarray(plant(u_id))
    noise = NOISE * np.ptp(y_id) * np.random.default_rng(0).standard_normal(len(t))
    y_val = np.asarray(plant(u_val))

    uniform, fitted, fits = {}, {}, {}
    for n in [2, 3, 4, 6, 8, 12, 16, 24, 32]:
        f = pj.uniform_pi(u_id, y_id + noise, n, initial_states=0.0)
        uniform[n] = rmse(f(u_val, 0.0), y_val)
    for n in [1, 2, 3, 4]:
        fits[n] = pj.fit_pi(u_id, y_id + noise, n, initial_states=0.0, key=jax.random.key(n))
        fitted[n] = rmse(fits[n](u_val, 0.0), y_val)
        print(f"n={n}: fitted {fitted[n]:.4g}", flush=True)
    target = 1.5 * min(fitted.values())
    need_uniform = next((n for n in sorted(uniform) if uniform[n] <= target), None)
    need_fitted = next(n for n in sorted(fitted) if fitted[n] <= target)

    # Compensation. Plant (b) adds an output nonlinearity and a lag of 1 % of a period.
    yd = 1.8 * np.sin(2 * np.pi * 0.5 * t) + 0.7 * np.sin(2 * np.pi * 1.7 * t)

    def plant_b(u):
        y = np.asarray(plant(np.asarray(u)))
        return lag(y + 0.04 * y**2, 0.5)

    y_b = plant_b(u_id) + noise
    model_a = fits[3]
    model_b = pj.fit_pi(u_id, y_b, 3, initial_states=0.0, key=jax.random.key(3))
    comp = {}
    for name, pl, model in [("exact_class", plant, model_a), ("model_error", plant_b, model_b)]:
        c = pj.evaluate_compensation(pl, model, yd, initial_states=0.0)
        comp[name] = {
            "model_identification_rmse": float(model.rmse),
            "rmse_linear_feedforward": float(c.rmse_linear),
            "rmse_inverse_feedforward": float(c.rmse_compensated),
            "error_removed_percent": 100 * (1 - float(c.rmse_compensated) / float(c.rmse_linear)),
        }
        comp[name]["_c"] = c
    res = {
        "plant": {"thresholds": R, "weights": W, "noise_fraction_of_range": NOISE},
        "validation_rmse_uniform_grid": uniform,
        "validation_rmse_fitted": fitted,
        "fitted_thresholds_3": fits[3].thresholds,
        "target_rmse": target,
        "plays_needed_uniform": need_uniform,
        "plays_needed_fitted": need_fitted,
        "compensation": {k: {kk: vv for kk, vv in v.items() if kk != "_c"} for k, v in comp.items()},
    }
    figure(t, yd, uniform, fitted, comp)
    print(pj.write_json(OUT / "fit_synthetic.json", res))


def figure(t, yd, uniform, fitted, comp):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(15, 4))
    a = axes[0]
    a.semilogy(list(uniform), list(uniform.values()), "o-", label="uniform grid (LS weights)")
    a.semilogy(list(fitted), list(fitted.values()), "s-", label="fitted thresholds")
    a.set(xlabel="number of plays", ylabel="validation RMSE", title="plays needed")
    a.legend(fontsize=8)
    for a, name in zip(axes[1:], ["exact_class", "model_error"]):
        c = comp[name]["_c"]
        a.plot(t, np.asarray(c.y_linear) - yd, lw=0.7, label=f"linear: {float(c.rmse_linear):.3f}")
        a.plot(t, np.asarray(c.y_compensated) - yd, lw=0.7, label=f"inverse PI: {float(c.rmse_compensated):.3f}")
        a.set(xlabel="time [s]", ylabel="tracking error", title=f"compensation, {name}")
        a.legend(fontsize=8)
    fig.tight_layout()
    pj.save_figure(fig, OUT / "fit_synthetic.png", dpi=110)


if __name__ == "__main__":
    main()
