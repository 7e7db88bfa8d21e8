"""The diagnosis's figure (`piest diagnose`'s report.png), as a library function."""

import numpy as np


def diagnosis_figure(report: dict):
    """Residuals and loops of the plain PI model and of the model with the named effects, on the
    record and (when the diagnosis had one) on the validation record.

    **Arguments:** `report`, from [`diagnose`][piest_jax.diagnose] (its plotting arrays under
    `_arrays`).

    **Returns:** a `matplotlib.figure.Figure` (2 x 2 panels, 2 x 3 with a validation record),
    made without pyplot: the backend and pyplot's figures stay as they were.
    """
    from matplotlib.figure import Figure

    a = report["_arrays"]
    has_val = "val_t" in a
    fig = Figure(figsize=(15 if has_val else 11, 7))
    ax = np.atleast_2d(fig.subplots(2, 3 if has_val else 2))
    names = " + ".join(report["effects"]) or "no effect"
    ax[0, 0].plot(a["t"], a["y"] - a["base"], lw=0.6, label=f"plain PI (RMSE {report['baseline_rmse']:.3g})")
    ax[0, 0].plot(a["t"], a["y"] - a["final"], lw=0.6, label=f"+ {names} (RMSE {report['final_rmse']:.3g})")
    ax[0, 0].set(xlabel="time", ylabel="residual y - model", title="residual before and after")
    ax[0, 0].legend(fontsize=8)
    ax[0, 1].plot(a["u"], a["y"], lw=0.5, color="0.6", label="measured")
    ax[0, 1].plot(a["u"], a["base"], lw=0.7, label="plain PI")
    ax[0, 1].set(xlabel="u", ylabel="y", title="loop before")
    ax[0, 1].legend(fontsize=8)
    ax[1, 1].plot(a["u"], a["y"], lw=0.5, color="0.6", label="measured")
    ax[1, 1].plot(a["u"], a["final"], lw=0.7, color="C1", label=f"+ {names}")
    ax[1, 1].set(xlabel="u", ylabel="y", title="loop after")
    ax[1, 1].legend(fontsize=8)
    ax[1, 0].plot(a["u"], a["y"] - a["base"], ".", ms=1, label="plain PI")
    ax[1, 0].plot(a["u"], a["y"] - a["final"], ".", ms=1, label=f"+ {names}")
    ax[1, 0].set(xlabel="u", ylabel="residual", title="residual against the input")
    ax[1, 0].legend(fontsize=8, markerscale=8)
    if has_val:
        v = report["validation"]
        ax[0, 2].plot(a["val_t"], a["val_y"] - a["val_base"], lw=0.6, label=f"plain PI ({v['baseline_rmse']:.3g})")
        ax[0, 2].plot(a["val_t"], a["val_y"] - a["val_final"], lw=0.6, label=f"after ({v['final_rmse']:.3g})")
        ax[0, 2].set(xlabel="time", ylabel="residual", title="validation record: residual")
        ax[0, 2].legend(fontsize=8)
        ax[1, 2].plot(a["val_u"], a["val_y"], lw=0.5, color="0.6", label="measured")
        ax[1, 2].plot(a["val_u"], a["val_final"], lw=0.7, color="C1", label="after")
        ax[1, 2].set(xlabel="u", ylabel="y", title="validation record: loop after")
        ax[1, 2].legend(fontsize=8)
    fig.tight_layout()
    return fig
