"""How an input excites a play bank: its guaranteed margin, its PE level, and the paper's RLS on it."""

import math

import jax.numpy as jnp
import numpy as np

from .._estimation.estimators import estimate
from .._estimation.rls import ContinuousRLS
from .._operators.play import play
from .draw_metrics import TARGET_ERROR, cumulative_information
from .exact_condition import exact_condition, pe_margin
from .pe import windowed_pe_levels


def time_to_error(error, times, target: float = TARGET_ERROR):
    """The first of `times` from which `error` stays at or below `target`; inf if it ends above.

    **Arguments:** `error` (K,) readings of an error; `times` (K,) when each was read.

    **Returns:** a time, or inf.
    """
    above = np.flatnonzero(np.asarray(error) > target)
    if above.size == 0:
        return float(times[0])
    if above[-1] == len(times) - 1:
        return math.inf
    return float(times[above[-1] + 1])


def worst_case_error(H, *, dt: float, P0: float, readings: int = 200):
    """The RLS weight error for the worst weight vector, 1 / (1 + P0 λ_min(A_k)), over time.

    A_k from `cumulative_information` on H / max |H| (the scale `estimate(..., rescale=True)`
    runs at; the relative error does not depend on y's scale). Depends on the input alone; it is
    what the margin bounds (Corollary 5 of `docs/excitation_condition.md`).

    **Arguments:** `H` (T, n) play outputs; `dt`, `P0` as the estimator's; `readings`, how many
    evenly spaced times to read it at (the last is T).

    **Returns:** `(k, error)`: sample counts (readings,) and the worst-case error after each.
    """
    H = jnp.asarray(H)
    T = H.shape[0]
    k, A = cumulative_information(H / jnp.max(jnp.abs(H)), dt, T, -(-T // min(readings, T)))
    lam = jnp.linalg.eigvalsh(0.5 * (A + jnp.swapaxes(A, -1, -2)))[:, 0]
    return np.asarray(k), np.asarray(1 / (1 + P0 * jnp.maximum(lam, 0.0)))


def excitation_report(u, r, weights, *, dt: float, window: int, P0: float = 1e3) -> dict:
    """How well `u` excites plays `r` (from zero initial states), and the paper's RLS on it.

    The RLS (`ContinuousRLS`, P0·I, Ŵ(0) = 0, on data rescaled to magnitude one) estimates
    `weights` from the noise-free output y = Σ w_j h_j.

    **Arguments:** `u` (T,); `r` (n,) thresholds; `weights` (n,) the true weights; `dt` the
    sampling step; `window` the PE window in samples (stride window // 10); `P0` the RLS gain.

    **Returns:** a dict: `margin` and `pe_level` (the smallest over windows of `pe_margin` and of
    λ_min of the window mean of h hᵀ), `margins` (windows,) each window's margin,
    `exact_condition_holds` (in every window),
    `time_to_1pct` (s; inf: the weight error does not stay below 1 %), `final_error`,
    `error` (T,) the relative weight error after each sample, and the same for the worst weight
    vector (`worst_case_error`): `time_to_1pct_worst` (read at 200 times),
    `final_error_worst`, `worst_k`, `worst_error`.
    """
    u = jnp.asarray(u)
    r = jnp.asarray(r, u.dtype)
    w = jnp.asarray(weights, u.dtype)
    stride = max(1, window // 10)
    H = play(u, r)
    est = estimate(ContinuousRLS(P0, dt), H, H @ w, rescale=True)
    err = np.asarray(jnp.linalg.norm(est.weights - w, axis=1) / jnp.linalg.norm(w))
    margins = np.asarray(pe_margin(H, u, r, window, stride=stride))
    k, worst = worst_case_error(H, dt=dt, P0=P0)
    return dict(
        margin=float(margins.min()),
        margins=margins,
        pe_level=float(jnp.min(windowed_pe_levels(H, window, stride=stride))),
        exact_condition_holds=bool(jnp.all(exact_condition(H, u, r, window, stride=stride).holds)),
        # The error after sample i is read at (i + 1) dt.
        time_to_1pct=time_to_error(err, (np.arange(err.size) + 1) * dt),
        final_error=float(err[-1]),
        time_to_1pct_worst=time_to_error(worst, k * dt),
        final_error_worst=float(worst[-1]),
        error=err,
        worst_k=k,
        worst_error=worst,
    )


def excitation_figure(inputs: dict, reports: dict, *, dt: float, window: int):
    """Inputs side by side: the signals, the RLS weight error over time, the margin per window.

    **Arguments:** `inputs`, name → u (T,); `reports`, name → [`excitation_report`][]'s dict;
    `dt`; `window` in samples.

    **Returns:** a `matplotlib.figure.Figure` (three panels), made without pyplot.
    """
    from matplotlib.figure import Figure

    fig = Figure(figsize=(16, 4.5))
    a1, a2, a3 = fig.subplots(1, 3)
    for name, u in inputs.items():
        rep = reports[name]
        t = np.arange(len(u)) * dt
        shown = slice(0, min(len(u), 2 * window))
        a1.plot(t[shown], np.asarray(u)[shown], lw=0.8, label=name)
        done = rep["time_to_1pct"]
        label = f"{name}: 1 % at {done:.3g} s" if math.isfinite(done) else f"{name}: not below 1 %"
        (line,) = a2.semilogy(t + dt, np.maximum(rep["error"], 1e-16), lw=0.8, label=label)
        a2.semilogy(
            rep["worst_k"] * dt,
            rep["worst_error"],
            ls="--",
            lw=1,
            color=line.get_color(),
            label=f"{name}: worst weights, final {rep['final_error_worst']:.2g}",
        )
        stride = max(1, window // 10)
        starts = np.arange(len(rep["margins"])) * stride * dt
        a3.semilogy(starts, np.maximum(rep["margins"], 1e-300), "o-", ms=3, label=f"{name}: min {rep['margin']:.3g}")
    a1.set(xlabel="t [s]", ylabel="u", title="inputs (first two windows)")
    a2.axhline(TARGET_ERROR, color="k", lw=1, ls=":")
    a2.set(xlabel="t [s]", ylabel="‖Ŵ − W‖ / ‖W‖", title="the paper's RLS (dashed: worst weights)")
    a3.set(xlabel="window start [s]", ylabel="guaranteed margin (lower bound on c1)", title="margin per window")
    for a in (a1, a2, a3):
        a.legend(fontsize=8)
    fig.tight_layout()
    return fig
