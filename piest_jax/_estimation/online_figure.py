"""The online estimate's figure (`piest estimate`'s estimate.png), as a library function."""

import numpy as np


def online_estimate_figure(result, *, title: str = "rls", t0: float = 0.0):
    """An online estimate over a record: the weights, the prediction error, the PE level per
    window and (for `ContinuousRLS`) the certificate, over time.

    **Arguments:**

    - `result`: an [`OnlineEstimate`][] (from [`estimate_record`][]).
    - `title`: the estimator's name, shown in the first panel's title.
    - `t0`: the record's first time, added to the result's times (which start at 0).

    **Returns:** a `matplotlib.figure.Figure` (2 x 2 panels), made without pyplot.
    """
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11, 7))
    ax = fig.subplots(2, 2)
    t, W = t0 + np.asarray(result.t), np.asarray(result.weights_trajectory)
    for j in range(W.shape[1]):
        ax[0, 0].plot(t, W[:, j], lw=0.8)
    ax[0, 0].set(xlabel="t [s]", ylabel="weights", title=f"{title}: weights")
    ax[0, 1].semilogy(t, np.maximum(np.asarray(result.error_rms), 1e-300), lw=0.8)
    ax[0, 1].set(
        xlabel="t [s]",
        ylabel="RMS prediction error",
        title=f"a-priori error (final RMSE {float(result.final_rmse):.3g})",
    )
    lv = np.asarray(result.pe_levels, float)
    ax[1, 0].semilogy(t0 + np.asarray(result.window_t), np.maximum(lv, 1e-300), "o-", ms=3)
    ax[1, 0].set(xlabel="window start [s]", ylabel="PE level (normalised)", title="excitation per window")
    bound = np.asarray(result.gram_bound)
    if len(bound):
        ax[1, 1].semilogy(t0 + np.asarray(result.bound_t), bound, "o-", ms=3)
        ax[1, 1].set(xlabel="t [s]", ylabel="bound on relative weight error", title="certificate (noise-free)")
    else:
        ax[1, 1].set_axis_off()
        ax[1, 1].text(0.5, 0.5, "certificate: ContinuousRLS only", ha="center", va="center")
    fig.tight_layout()
    return fig
