"""The identification figures `piest fit` and `piest compensate` draw, as library functions.

Each builds a `matplotlib.figure.Figure` directly: no pyplot, no backend switch, so they are
safe in any program (show one in a notebook with `display(fig)`, save it with
[`save_figure`][]).
"""

import numpy as np

# Points per drawn line. A figure resolves about a thousand columns, so a longer record is drawn
# from fewer points chosen to look the same (`envelope`, `loop_points`); its numbers (the RMSE,
# the band's coverage) use every sample. Drawing 10^7 samples whole took 3 GB and minutes.
MAX_POINTS = 100_000


def envelope(t, y, bins: int = MAX_POINTS // 2):
    """A time series reduced to each bin's smallest and largest value, in time order.

    **Arguments:** `t`, `y` (T,); `bins`, the number of bins of consecutive samples.

    **Returns:** `(t, y)` of at most 2 `bins` points (the series itself when it is no longer),
    drawn as the same ink: every excursion of the series is in it.
    """
    t, y = np.asarray(t), np.asarray(y)
    T = y.shape[0]
    if T <= 2 * bins:
        return t, y
    k = -(-T // bins)
    n = T // k * k
    blocks = y[:n].reshape(-1, k)
    base = np.arange(0, n, k)
    lo, hi = base + np.argmin(blocks, axis=1), base + np.argmax(blocks, axis=1)
    idx = np.sort(np.concatenate([lo, hi, np.arange(n, T)]))
    return t[idx], y[idx]


def band_envelope(t, lower, upper, bins: int = MAX_POINTS // 2):
    """A band reduced to each bin's lowest lower and highest upper edge (at the bin's centre).

    **Returns:** `(t, lower, upper)` of at most `bins` + 1 points (the band itself when short).
    """
    t, lower, upper = (np.asarray(a) for a in (t, lower, upper))
    T = t.shape[0]
    if T <= 2 * bins:
        return t, lower, upper
    k = -(-T // bins)
    edges = np.arange(0, T, k)
    return (t[np.minimum(edges + k // 2, T - 1)], np.minimum.reduceat(lower, edges),
            np.maximum.reduceat(upper, edges))


def loop_points(u, max_points: int = MAX_POINTS):
    """Indices of a loop's samples to draw: every k-th one and the input's reversals.

    A loop turns where the input reverses, so those samples are kept (when there are fewer than
    `max_points`) and a stride thins the rest.

    **Returns:** sorted indices (all of them for a record of at most `max_points` samples).
    """
    u = np.asarray(u)
    T = u.shape[0]
    if T <= max_points:
        return np.arange(T)
    du = np.diff(u)
    turns = np.flatnonzero(du[1:] * du[:-1] < 0) + 1
    keep = np.arange(0, T, -(-T // max_points))
    if turns.size < max_points:
        keep = np.union1d(keep, turns)
    return np.union1d(keep, [T - 1])


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
    drawn = loop_points(uu)
    a1.plot(uu[drawn], yu[drawn], "k", lw=0.7, label="measured")
    a1.plot(uu[drawn], mu[drawn], "C1", lw=0.7, label="model")
    a1.set(xlabel="input u", ylabel="output y", title=f"{title}: loop")
    a1.legend(fontsize=8, loc="upper left")
    if band is not None:
        lower, upper = (np.asarray(b) for b in band)
        inside = float(np.mean(((y >= lower) & (y <= upper))[used]))
        a2.fill_between(*band_envelope(t, lower - ym, upper - ym), color="C1", alpha=0.3, lw=0,
                        label=f"band ({100 * inside:.1f} % inside)")
    a2.plot(*envelope(t, y - ym), lw=0.6)
    if mask is not None and not np.all(np.asarray(mask)):
        a2.axvspan(t[0], t[np.argmax(used)], color="0.85", label="not fitted")
        # Scaled to the fitted samples: a transient left out would otherwise flatten the rest.
        e = (y - ym)[used]
        pad = 0.1 * max(np.ptp(e), 1e-12)
        a2.set_ylim(e.min() - pad, e.max() + pad)
    if band is not None or mask is not None and not np.all(np.asarray(mask)):
        a2.legend(fontsize=8, loc="upper right")
    rmse = float(np.sqrt(np.mean((ym[used] - y[used]) ** 2)))
    a2.set(xlabel="time", ylabel="y - model", title=f"residual, RMSE {rmse:.4g}")
    fig.tight_layout()
    return fig


def compensation_figure(t, desired, u):
    """A feedforward compensation: the desired output and the input over time, and the input
    against the desired output (the inverse loop).

    **Arguments:** `t`, `desired`, `u`: time, the desired output and the feedforward input
    (e.g. from [`feedforward`][]), (T,) each.

    **Returns:** a `matplotlib.figure.Figure` (11 x 4 inches), made without pyplot.
    """
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11, 4))
    a1, a2 = fig.subplots(1, 2)
    a1.plot(t, desired, "k", lw=0.8, label="desired output")
    a1.plot(t, u, "C1", lw=0.8, label="feedforward input")
    a1.set(xlabel="time", title="compensation")
    a1.legend(fontsize=8)
    a2.plot(desired, u, lw=0.8)
    a2.set(xlabel="desired output", ylabel="feedforward input", title="inverse loop")
    fig.tight_layout()
    return fig
