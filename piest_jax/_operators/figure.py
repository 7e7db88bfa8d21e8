"""A PI operator's figure (`piest simulate`'s loop.png), as a library function."""

import numpy as np

# Many plays would make an unreadable (and slow) plot: an even selection of them is drawn.
MAX_PLOTTED_PLAYS = 12


def loop_figure(t, u, y, plays, thresholds):
    """A PI operator run on an input: its y-u loop, and the play outputs over time (at most 12,
    evenly chosen, when there are more).

    **Arguments:** `t`, `u`, `y`: time, input and output, (T,) each; `plays`: the play outputs
    (T, n) (e.g. `PIOperator.regressor(u)`); `thresholds`: the plays' thresholds (n,).

    **Returns:** a `matplotlib.figure.Figure` (10 x 4 inches), made without pyplot.
    """
    from matplotlib.figure import Figure

    H = np.asarray(plays)
    fig = Figure(figsize=(10, 4))
    a1, a2 = fig.subplots(1, 2)
    a1.plot(u, y, lw=1)
    a1.set(xlabel="input u", ylabel="output y", title="PI operator loop")
    shown = np.unique(np.linspace(0, H.shape[1] - 1, min(H.shape[1], MAX_PLOTTED_PLAYS)).round())
    for j in shown.astype(int):
        a2.plot(t, H[:, j], lw=1, label=f"r = {float(thresholds[j]):.3g}")
    a2.set(xlabel="time [s]", ylabel="play output", title="play outputs")
    a2.legend(fontsize=8)
    fig.tight_layout()
    return fig
