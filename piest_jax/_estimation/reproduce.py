"""The paper's Figs. 5 and 6: continuous-time RLS on a three-play PI operator.

Both use thresholds r = (0, 10/3, 20/3), dt = 1 ms, t ∈ [0, 1] s and Ŵ(0) = 0:

- Fig. 5: u = 10 sin(2π·5t), true weights (1, 3, 5);
- Fig. 6: u = 10 sin(10πt) + 5 sin(2πt) (minor loops), true weights (2, 6, 8).

The paper does not state P0. With its normalisation (division by m² = (1 + hᵀh)²) each 1 ms sample
adds only about 1e-3 / (1 + hᵀh)² ≈ 1e-7 to the information matrix, so P0 must be large: P0 = 1e8·I
brings every weight within 1 % in about 0.03 s and within 1e-4 relative by t = 1 s. The
second panel shows how the convergence time scales with P0 for both normalisations: below about
1e5 (paper normalisation) the weights are not within 1 % by t = 1 s; above about 1e9 the time
stops improving, because the largest-threshold play stays at 0 (and its weight cannot be seen)
until u first exceeds r_3 = 20/3, at t ≈ 0.023 s. The left panel's inset shows the relative error
norm under the convergence certificate computed from the regressor alone.
"""

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._excitation.pe import assumption1_ratio, pe_level
from .._operators.pi import PIOperator
from .batch import settle_index, trajectory
from .certificate import convergence_certificate
from .rls import NORMALISATIONS, ContinuousRLS, Normalisation

THRESHOLDS = (0.0, 10.0 / 3.0, 20.0 / 3.0)
DT = 1e-3
DURATION = 1.0
DEFAULT_P0 = 1e8
SWEEP_P0 = tuple(10.0 ** np.arange(2.0, 12.5, 0.5))
FIGURES = ("fig5", "fig6")


@dataclasses.dataclass(frozen=True)
class PaperCase:
    """One of the paper's simulation settings."""

    name: str
    weights: tuple[float, ...]
    amplitudes: tuple[float, ...]
    frequencies: tuple[float, ...]
    description: str
    window_s: float  # the PE window T0: one period of the 5 Hz component

    def time(self) -> np.ndarray:
        return np.arange(int(round(DURATION / DT)) + 1) * DT

    def input(self) -> np.ndarray:
        t = self.time()
        return sum((a * np.sin(2 * np.pi * f * t) for a, f in zip(self.amplitudes, self.frequencies)), np.zeros_like(t))


CASES = {
    "fig5": PaperCase("fig5", (1.0, 3.0, 5.0), (10.0,), (5.0,), "u = 10 sin(2 pi 5 t)", 0.2),
    "fig6": PaperCase(
        "fig6",
        (2.0, 6.0, 8.0),
        (10.0, 5.0),
        (5.0, 1.0),
        "u = 10 sin(10 pi t) + 5 sin(2 pi t)",
        0.2,
    ),
}


def time_to_tolerance(t, weights, truth, rtol: float = 0.01) -> float:
    """The first time after which every weight stays within `rtol` (relative) of its true value.

    **Arguments:** `t` (T,), `weights` (T, n) estimates, `truth` (n,), `rtol`.

    **Returns:** the time in the units of `t`, or inf when the last sample is still outside.
    """
    t = np.asarray(t)
    w = np.asarray(weights)
    truth = np.asarray(truth)
    ok = np.all(np.abs(w - truth) <= rtol * np.abs(truth), axis=1)
    if not ok[-1]:
        return float("inf")
    bad = np.nonzero(~ok)[0]
    return float(t[0] if bad.size == 0 else t[bad[-1] + 1])


@eqx.filter_jit
def _run(estimator, sweep, H, y, truth):
    """The estimate at the chosen P0 and, for each normalisation, the settling index over the P0
    sweep (`sweep`: estimators stacked along P0).

    Everything it is given was checked outside, on concrete values: a check of a traced value is
    a host callback, and JAX keeps no program with one in its persistent compilation cache, so a
    second `piest reproduce` would compile this one again.
    """
    w0 = jnp.zeros_like(truth)
    result = trajectory(estimator, H, y, w0)

    def settles(est):
        w, _ = trajectory(est, H, y, w0)
        return settle_index(w, truth, 0.01)

    return result, {n: jax.vmap(settles)(stacked) for n, stacked in sweep.items()}


def _stacked(estimators):
    """Estimators of one structure as one, each leaf stacked along a new first axis (for vmap)."""
    return jax.tree.map(lambda *leaves: jnp.stack(leaves), *estimators)


def reproduce(name: str, *, P0: float = DEFAULT_P0, normalisation: Normalisation = "paper") -> dict:
    """Run one of the paper's figures and collect everything the figure and the report need.

    **Arguments:** `name`, `"fig5"` or `"fig6"`; `P0`, the initial gain (P0·I);
    `normalisation`, see [`ContinuousRLS`][].

    **Returns:** a dict with the JSON report fields (`weights_true`, `weights_final`,
    `final_abs_error`, `time_to_1pct`, `P0`, `estimator`, ...) and, under `"_arrays"`, the
    trajectories for plotting.
    """
    if name not in CASES:
        raise ValueError(f"unknown figure {name!r}; choose one of {FIGURES}")
    if not (np.isfinite(P0) and P0 > 0):
        raise ValueError(f"P0 must be positive and finite, got {P0}")
    case = CASES[name]
    t = case.time()
    dtype = jnp.result_type(float)
    u = jnp.asarray(case.input(), dtype)
    truth = jnp.asarray(case.weights, dtype)
    window = int(round(case.window_s / DT))
    H = PIOperator(jnp.asarray(THRESHOLDS, dtype), truth).regressor(u)
    y = H @ truth
    estimator = ContinuousRLS(jnp.asarray(P0, dtype), DT, normalisation=normalisation)
    sweep = {n: _stacked([ContinuousRLS(p, DT, normalisation=n) for p in SWEEP_P0]) for n in NORMALISATIONS}
    res, idx = _run(estimator, sweep, H, y, truth)
    cert = convergence_certificate(H, jnp.asarray(P0, dtype), DT, window, normalisation=normalisation)
    c1 = pe_level(H, window)
    rho = assumption1_ratio(u, THRESHOLDS[-1], window)
    w = np.asarray(res[0])
    if not np.all(np.isfinite(w)):
        # Only reachable near the float range (P0 beyond about 1e200): say so instead of plotting NaN.
        raise ValueError(f"P0 = {P0:g} overflows {w.dtype} in the estimator; use a smaller P0")
    tsweep = {n: [float(t[i]) if i < len(t) else float("inf") for i in np.asarray(v)] for n, v in idx.items()}
    final = w[-1]
    truth_np = np.asarray(case.weights)
    u_np = np.asarray(u)
    rel = np.linalg.norm(w - truth_np, axis=1) / np.linalg.norm(truth_np)
    eps = float(np.finfo(w.dtype).eps)
    reach = np.nonzero(u_np > THRESHOLDS[-1])[0]
    return {
        "figure": name,
        "input": case.description,
        "thresholds": list(THRESHOLDS),
        "dt": DT,
        "duration": DURATION,
        "estimator": "ContinuousRLS",
        "normalisation": normalisation,
        "P0": P0,
        "initial_weights": [0.0] * len(truth_np),
        "weights_true": truth_np,
        "weights_final": final,
        "final_abs_error": np.abs(final - truth_np),
        "final_rel_error": np.abs(final - truth_np) / np.abs(truth_np),
        "time_to_1pct": time_to_tolerance(t, w, truth_np, 0.01),
        "time_input_exceeds_r_max": float(t[reach[0]]) if reach.size else float("inf"),
        "pe_window_s": case.window_s,
        "pe_level_c1": float(c1),
        "assumption1_ratio": float(rho),
        "certificate_final_rel_bound": float(cert.gram_bound[-1]),
        # the bound is for exact arithmetic; allow rounding (100 eps of the working precision)
        "certificate_holds": bool(np.all(rel <= np.asarray(cert.gram_bound) + 100 * eps)),
        "final_rel_error_norm": float(np.linalg.norm(final - truth_np) / np.linalg.norm(truth_np)),
        "sweep": {"P0": list(SWEEP_P0), "time_to_1pct": tsweep},
        "_arrays": {"t": t, "weights": w, "error": np.asarray(res[1]), "bound": cert.gram_bound},
    }


def figure(report: dict):
    """The figure for one report: weight errors over time, and convergence time against P0.

    **Arguments:** `report`, from [`reproduce`][].

    **Returns:** a `matplotlib.figure.Figure`, made without pyplot: the backend and pyplot's
    current figure stay as they were (show it with `display(fig)` or save it with `fig.savefig`).
    """
    from matplotlib.figure import Figure

    arr = report["_arrays"]
    t, w = arr["t"], arr["weights"]
    truth = np.asarray(report["weights_true"])
    fig = Figure(figsize=(11, 4))
    a1, a2 = fig.subplots(1, 2)
    for j in range(w.shape[1]):
        a1.plot(t, truth[j] - w[:, j], lw=1.2, label=f"ω̃{j + 1} (ω{j + 1} = {truth[j]:g})")
    a1.axhline(0, color="k", lw=0.5)
    a1.set(xlabel="time [s]", ylabel="weight error ω − ω̂", xlim=(0, t[-1]))
    a1.legend(fontsize=8, loc="upper right")
    ax_in = a1.inset_axes([0.42, 0.3, 0.53, 0.35])
    rel = np.linalg.norm(w - truth, axis=1) / np.linalg.norm(truth)
    ax_in.semilogy(t, np.maximum(rel, 1e-16), lw=1, label="‖ω̃‖ / ‖ω‖")
    ax_in.semilogy(t, arr["bound"], "k--", lw=0.8, label="certificate")
    ax_in.legend(fontsize=6, loc="upper right")
    ax_in.tick_params(labelsize=6)
    sw = report["sweep"]
    p0s = np.asarray(sw["P0"])
    for norm, style, color in (("paper", "o-", "C0"), ("standard", "s--", "C1")):
        ts = np.asarray([np.inf if v is None else v for v in sw["time_to_1pct"][norm]], float)
        ok = np.isfinite(ts)
        label = "m = 1 + hᵀh, /m² (paper)" if norm == "paper" else "m² = 1 + hᵀh"
        a2.loglog(p0s[ok], np.maximum(ts[ok], DT), style, color=color, ms=4, label=label)
        a2.loglog(p0s[~ok], np.full((~ok).sum(), DURATION), "^", color=color, ms=5, mfc="none")
    a2.axvline(report["P0"], color="gray", lw=0.8, ls=":", label=f"chosen P0 = {report['P0']:.0e}")
    a2.axhline(report["time_input_exceeds_r_max"], color="k", lw=0.6, ls="-.", label="u first exceeds r_max")
    a2.set(xlabel="P0", ylabel="time to 1 % [s]")
    # Titles at a stated height: placed automatically, each would be laid out against the tick
    # labels of its axes at every draw (about half of the figure's drawing time, measured).
    a1.set_title(f"{report['figure']}: {report['input']}, P0 = {report['P0']:.0e}·I", y=1.0)
    a2.set_title("convergence time vs P0 (open ▲: not within 1 s)", y=1.0)
    a2.legend(fontsize=8)
    # Fixed margins rather than `tight_layout`, which measures every tick label and took half a
    # second a figure (a second `piest reproduce all` is otherwise mostly start-up).
    fig.subplots_adjust(left=0.065, right=0.99, bottom=0.13, top=0.92, wspace=0.2)
    return fig


def public_report(report: dict) -> dict:
    """The report without the plotting arrays, ready for `write_json`."""
    return {k: v for k, v in report.items() if not k.startswith("_")}
