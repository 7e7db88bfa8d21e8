"""The identification figures `piest fit` and `piest compensate` draw, as library functions.

Each builds a `matplotlib.figure.Figure` directly: no pyplot, no backend switch, so they are
safe in any program (show one in a notebook with `display(fig)`, save it with
[`save_figure`][]).
"""

import numpy as np


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
    a1.plot(u[used], y[used], "k", lw=0.7, label="measured")
    a1.plot(u[used], ym[used], "C1", lw=0.7, label="model")
    a1.set(xlabel="input u", ylabel="output y", title=f"{title}: loop")
    a1.legend(fontsize=8)
    if band is not None:
        lower, upper = (np.asarray(b) for b in band)
        inside = float(np.mean(((y >= lower) & (y <= upper))[used]))
        a2.fill_between(t, lower - ym, upper - ym, color="C1", alpha=0.3, lw=0,
                        label=f"band ({100 * inside:.1f} % inside)")
    a2.plot(t, y - ym, lw=0.6)
    if mask is not None and not np.all(np.asarray(mask)):
        a2.axvspan(t[0], t[np.argmax(used)], color="0.85", label="not fitted")
        # Scaled to the fitted samples: a transient left out would otherwise flatten the rest.
        e = (y - ym)[used]
        pad = 0.1 * max(np.ptp(e), 1e-12)
        a2.set_ylim(e.min() - pad, e.max() + pad)
    if band is not None or mask is not None and not np.all(np.asarray(mask)):
        a2.legend(fontsize=8)
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
