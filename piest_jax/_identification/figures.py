"""The identification figures `piest fit` and `piest compensate` draw, as library functions.

Each builds a `matplotlib.figure.Figure` directly: no pyplot, no backend switch, so they are
safe in any program (show one in a notebook with `display(fig)`, save it with
[`save_figure`][]).
"""

import numpy as np

# A figure resolves some hundreds of pixel columns, and the renderer's work grows with the length
# of the lines it draws. A long record is therefore drawn from the extremes of `BINS` bins of
# consecutive samples (`bin_extremes`, shaded between them: every excursion is in the ink) and its
# loop from `STRETCHES` evenly spaced stretches of the record (`loop_stretches`), at most
# `MAX_POINTS` samples in all; the numbers (the RMSE, the band's coverage) use every sample.
# Drawn whole, 10^7 samples took 3 GB and minutes.
MAX_POINTS = 100_000
BINS = 2000
STRETCHES = 50


def bin_extremes(t, lower, upper, bins: int = BINS):
    """A series (or a band) reduced to each bin's lowest `lower` and highest `upper` value.

    **Arguments:** `t`, `lower`, `upper` (T,) (pass a series twice for its own envelope);
    `bins`, the number of bins of consecutive samples.

    **Returns:** `(t, lower, upper)`: at each bin's first sample, the bin's extremes; the inputs
    themselves when T <= 2 `bins`.
    """
    t, lower, upper = (np.asarray(a) for a in (t, lower, upper))
    T = t.shape[0]
    if T <= 2 * bins:
        return t, lower, upper
    edges = np.arange(0, T, -(-T // bins))
    return t[edges], np.minimum.reduceat(lower, edges), np.maximum.reduceat(upper, edges)


def loop_stretches(T: int, max_points: int = MAX_POINTS, stretches: int = STRETCHES):
    """Which samples of a long record a loop figure draws: evenly spaced stretches of it.

    **Returns:** `(index, gaps)`: sample indices (all of them when T <= `max_points`) and a
    boolean mask, True where a stretch ends (the line is broken there).
    """
    if T <= max_points:
        return np.arange(T), np.zeros(T, bool)
    length = max_points // stretches
    starts = np.linspace(0, T - length, stretches).astype(int)
    index = (starts[:, None] + np.arange(length)[None, :]).ravel()
    gaps = np.zeros(index.size, bool)
    gaps[length - 1 :: length] = True
    return index, gaps


def _broken(a, gaps):
    """`a` with a NaN after every True in `gaps` (matplotlib breaks a line at NaN)."""
    return np.insert(np.asarray(a, float), np.flatnonzero(gaps) + 1, np.nan)


def residual_limits(e) -> tuple[float, float, bool]:
    """Axis limits for a residual: its whole range, or, when a few samples (a transient) reach
    more than its 0.5-99.5 % range again beyond it, that range padded; and whether any sample
    lies beyond the limits."""
    e = np.asarray(e, float)
    lo, hi = (float(v) for v in np.percentile(e, [0.5, 99.5]))
    span = max(hi - lo, 1e-12)
    if e.min() >= lo - span and e.max() <= hi + span:
        lo, hi, span = float(e.min()), float(e.max()), max(float(np.ptp(e)), 1e-12)
    lo, hi = lo - 0.1 * span, hi + 0.1 * span
    return lo, hi, bool(e.min() < lo or e.max() > hi)


def fit_figure(record, prediction, *, title: str = "fit", mask=None, band=None):
    """A model against a record: the measured and modelled loops, and the residual over time.

    **Arguments:**

    - `record`: the [`Record`][] (t, u, y).
    - `prediction`: the model's output on it, (T,) (e.g. `fit(record.u)` or a
      [`Comparison`][]'s `prediction`).
    - `title`: what the panels are titled after (`"fit"`, `"validation"`).
    - `mask`: (T,) 1 on the fitted samples, 0 on those left out (drawn shaded, and out of the
      loop and the RMSE), or None.
    - `band`: `(lower, upper)` (T,) each, a band around the prediction (e.g. a
      [`PredictionBand`][]'s `interval()`), shaded on the residual panel as the band the
      residual should stay in; or None.

    **Returns:** a `matplotlib.figure.Figure` (11 x 4 inches), made without pyplot.
    """
    from matplotlib.figure import Figure

    t, u, y = record.t, record.u, record.y
    ym = np.asarray(prediction)
    used = slice(None) if mask is None else np.asarray(mask) > 0
    fig = Figure(figsize=(11, 4))
    a1, a2 = fig.subplots(1, 2)
    uu, yu, mu = u[used], y[used], ym[used]
    drawn, gaps = loop_stretches(uu.shape[0])
    part = "" if drawn.size == uu.size else f" ({STRETCHES} stretches of {drawn.size // STRETCHES})"
    ud = _broken(uu[drawn], gaps)
    a1.plot(ud, _broken(yu[drawn], gaps), "k", lw=0.7, label="measured" + part)
    a1.plot(ud, _broken(mu[drawn], gaps), "C1", lw=0.7, label="model")
    a1.set(xlabel="input u", ylabel="output y", title=f"{title}: loop")
    a1.legend(fontsize=8, loc="upper left")
    if band is not None:
        lower, upper = (np.asarray(b) for b in band)
        inside = float(np.mean(((y >= lower) & (y <= upper))[used]))
        # Above the residual, translucent, so both show.
        a2.fill_between(
            *bin_extremes(t, lower - ym, upper - ym),
            color="C1",
            alpha=0.3,
            lw=0,
            zorder=3,
            label=f"band ({100 * inside:.1f} % inside)",
        )
    e = y - ym
    if e.shape[0] > 2 * BINS:
        a2.fill_between(*bin_extremes(t, e, e), color="C0", lw=0.6)
    else:
        a2.plot(t, e, lw=0.6)
    if mask is not None and not np.all(np.asarray(mask)):
        a2.axvspan(t[0], t[np.argmax(np.asarray(mask) > 0)], color="0.85", label="not fitted")
    # Scaled to the bulk of the fitted samples' residual: a start-up transient, fitted or left
    # out, would otherwise flatten the rest into a line. What goes beyond is said.
    lo, hi, clipped = residual_limits(e[used])
    a2.set_ylim(lo, hi)
    if clipped:
        eu = e[used]
        a2.text(
            0.01,
            0.02,
            f"beyond the axis: the residual reaches {eu.min():.3g} and {eu.max():.3g}",
            transform=a2.transAxes,
            fontsize=7,
            color="0.3",
        )
    if band is not None or mask is not None and not np.all(np.asarray(mask)):
        a2.legend(fontsize=8, loc="upper right")
    rmse = float(np.sqrt(np.mean(e[used] ** 2)))
    unit = "sample" if getattr(record, "time_is_index", False) else "time [s]"
    a2.set(xlabel=unit, ylabel="y - model", title=f"residual, RMSE {rmse:.4g}")
    fig.tight_layout()
    return fig


def compensation_figure(t, desired, u, *, time_unit: str = "s", input_range=None):
    """A feedforward compensation: the desired output and the input over time, each on its own
    axis, and the input against the desired output (the inverse loop).

    **Arguments:** `t`, `desired`, `u`: time, the desired output and the feedforward input
    (e.g. from [`feedforward`][]), (T,) each; `time_unit`, the time axis's unit; `input_range`,
    the (lo, hi) input range the model was fitted on, shaded where given.

    **Returns:** a `matplotlib.figure.Figure` (11 x 5 inches), made without pyplot.
    """
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11, 5))
    grid = fig.add_gridspec(2, 2, width_ratios=(1.4, 1))
    a1 = fig.add_subplot(grid[0, 0])
    a0 = fig.add_subplot(grid[1, 0], sharex=a1)
    a2 = fig.add_subplot(grid[:, 1])
    a1.plot(t, desired, "k", lw=0.8)
    a1.set(ylabel="desired output", title="compensation")
    a1.tick_params(labelbottom=False)
    a0.plot(t, u, "C1", lw=0.8)
    a0.set(xlabel=f"time [{time_unit}]", ylabel="feedforward input")
    if input_range is not None:
        for ax in (a0, a2):
            ax.axhspan(*input_range, color="0.9", zorder=0, label="fitted input range")
        a0.legend(fontsize=8, loc="upper right")
    a2.plot(desired, u, lw=0.8)
    a2.set(xlabel="desired output", ylabel="feedforward input", title="inverse loop")
    fig.tight_layout()
    return fig
