"""The diagnosis's figure (`piest diagnose`'s report.png), as a library function."""

import numpy as np


def diagnosis_figure(diagnosis):
    """Residuals and loops of the plain PI model and of the model with the named effects, on the
    record and (when the diagnosis had one) on the validation record.

    **Arguments:** `diagnosis`, a [`Diagnosis`][piest_jax.Diagnosis] (from
    [`diagnose`][piest_jax.diagnose]).

    **Returns:** a `matplotlib.figure.Figure` (2 x 2 panels, 2 x 3 with a validation record),
    made without pyplot: the backend and pyplot's figures stay as they were.
    """
    from matplotlib.figure import Figure

    d, v = diagnosis, diagnosis.validation
    t, u, y = d.record.t, d.record.u, d.record.y
    base, final = d.baseline_prediction, d.final_prediction
    has_val = v is not None
    fig = Figure(figsize=(15 if has_val else 11, 7))
    ax = np.atleast_2d(fig.subplots(2, 3 if has_val else 2))
    names = " + ".join(d.effects) or "no effect"
    ax[0, 0].plot(t, y - base, lw=0.6, label=f"plain PI (RMSE {d.baseline_rmse:.3g})")
    ax[0, 0].plot(t, y - final, lw=0.6, label=f"+ {names} (RMSE {d.final_rmse:.3g})")
    ax[0, 0].set(xlabel="time", ylabel="residual y - model", title="residual before and after")
    ax[0, 0].legend(fontsize=8)
    ax[0, 1].plot(u, y, lw=0.5, color="0.6", label="measured")
    ax[0, 1].plot(u, base, lw=0.7, label="plain PI")
    ax[0, 1].set(xlabel="u", ylabel="y", title="loop before")
    ax[0, 1].legend(fontsize=8)
    ax[1, 1].plot(u, y, lw=0.5, color="0.6", label="measured")
    ax[1, 1].plot(u, final, lw=0.7, color="C1", label=f"+ {names}")
    ax[1, 1].set(xlabel="u", ylabel="y", title="loop after")
    ax[1, 1].legend(fontsize=8)
    ax[1, 0].plot(u, y - base, ".", ms=1, label="plain PI")
    ax[1, 0].plot(u, y - final, ".", ms=1, label=f"+ {names}")
    ax[1, 0].set(xlabel="u", ylabel="residual", title="residual against the input")
    ax[1, 0].legend(fontsize=8, markerscale=8)
    if has_val:
        vt, vu, vy = v.record.t, v.record.u, v.record.y
        ax[0, 2].plot(vt, vy - v.baseline_prediction, lw=0.6, label=f"plain PI ({v.baseline_rmse:.3g})")
        ax[0, 2].plot(vt, vy - v.final_prediction, lw=0.6, label=f"after ({v.final_rmse:.3g})")
        ax[0, 2].set(xlabel="time", ylabel="residual", title="validation record: residual")
        ax[0, 2].legend(fontsize=8)
        ax[1, 2].plot(vu, vy, lw=0.5, color="0.6", label="measured")
        ax[1, 2].plot(vu, v.final_prediction, lw=0.7, color="C1", label="after")
        ax[1, 2].set(xlabel="u", ylabel="y", title="validation record: loop after")
        ax[1, 2].legend(fontsize=8)
    fig.tight_layout()
    return fig
