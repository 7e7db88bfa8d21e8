"""The Monte Carlo map's figure (`piest montecarlo`'s pe_map.png), as a library function."""

import numpy as np

from .families import FAMILIES
from .map_result import PEMap
from .map_settings import numerical_tolerance


def pe_map_figure(result: PEMap):
    """The PE map: the PE level against the Assumption 1 ratio by family, the fraction of
    persistently exciting draws against that ratio, the weight error against the PE level, the
    PE level against its margin, and the RLS weight error after the record against the bound
    the margins guarantee.

    **Arguments:** `result`, a [`PEMap`][] from [`pe_map`][] (its settings' `dtype` sets the
    tolerance below which a PE level is rounding).

    **Returns:** a `matplotlib.figure.Figure` (five panels), made without pyplot.
    """
    from matplotlib.figure import Figure

    res = result
    settings = res.settings
    tol = numerical_tolerance(settings.dtype)
    rho = res.rho
    c1n = res.c1_normalised
    pe = res.pe
    settled = res.settled is not None
    floor = tol / 10
    fig = Figure(figsize=(25, 4.5))
    a1, a2, a3, a4, a5 = fig.subplots(1, 5)
    for f in settings.families:
        m = res.family == f
        a1.scatter(rho[m], np.maximum(c1n[m], floor), s=6, alpha=0.6, label=FAMILIES[f])
    a1.axvline(1.0, color="k", lw=1, ls="--", label="ρ = 1 (Assumption 1)")
    a1.axhline(tol, color="r", lw=1, ls=":", label=f"tolerance {tol:.1e}")
    a1.set(
        xscale="log",
        yscale="log",
        xlabel="Assumption 1 ratio ρ(T0)",
        ylabel="normalised PE level c1 (λmin/λmax)",
        title="PE level against Assumption 1",
    )
    a1.legend(fontsize=7, markerscale=2)
    edges = np.unique(np.quantile(rho, np.linspace(0, 1, 16)))
    idx = np.clip(np.searchsorted(edges, rho, side="right") - 1, 0, len(edges) - 2)

    def fraction(flags):
        """The fraction of draws with `flags` in each bin of rho (NaN for an empty bin)."""
        return [flags[idx == b].mean() if np.any(idx == b) else np.nan for b in range(len(edges) - 1)]

    mids = np.sqrt(np.maximum(edges[:-1], 1e-6) * np.maximum(edges[1:], 1e-6))
    a2.plot(mids, fraction(pe), "o-", label="PE (settled exactly)" if settled else "PE (c1 > tolerance)")
    a2.plot(mids, fraction(res.exact), "x-.", label="exact condition holds")
    a2.plot(mids, fraction(res.sharper), "s--", label="sharper condition holds")
    a2.axvline(1.0, color="k", lw=1, ls="--")
    a2.set(xscale="log", ylim=(-0.05, 1.05), xlabel="ρ(T0)", ylabel="fraction of draws", title="fraction PE against ρ")
    a2.legend(fontsize=8)
    err = np.maximum(res.weight_error, 1e-18)
    a3.scatter(np.maximum(c1n, floor), err, s=6, alpha=0.5, c=np.where(pe, "C0", "C3"))
    a3.axvline(tol, color="r", lw=1, ls=":")
    a3.set(
        xscale="log",
        yscale="log",
        xlabel="normalised PE level c1",
        ylabel="RLS ‖Ŵ − W‖ / ‖W‖ after the record",
        title="weight error against c1",
    )
    # The margin (a lower bound on c1 from the input's swings between events) against c1.
    ok = res.exact & (res.margin > 0) & (res.c1 > 0)
    if np.any(ok):
        m, c = res.margin[ok], res.c1[ok]
        a4.scatter(m, c, s=6, alpha=0.5)
        lo, hi = min(m.min(), c.min()), max(m.max(), c.max())
        a4.plot([lo, hi], [lo, hi], "k--", lw=1, label="c1 = margin")
        a4.legend(fontsize=8)
    a4.set(
        xscale="log",
        yscale="log",
        xlabel="margin (lower bound from the input)",
        ylabel="PE level c1",
        title="c1 against its guaranteed margin",
    )
    # The weight error after the record against the margins' guarantee: measured <= worst case
    # over weight vectors <= the guarantee, for every draw.
    bound = res.guaranteed_error
    a5.scatter(bound, np.maximum(res.worst_error, 1e-18), s=6, alpha=0.5, label="worst case over W: 1/(1 + P0 λmin(A))")
    a5.scatter(bound, err, s=4, alpha=0.4, c="C3", label="this draw's W")
    lo = min(bound.min(), 1e-6)
    a5.plot([lo, 1], [lo, 1], "k--", lw=1, label="= guarantee")
    a5.set(
        xscale="log",
        yscale="log",
        xlabel="guaranteed error bound from the margins",
        ylabel="RLS weight error after the record",
        title=f"convergence: {int((res.guaranteed_samples_to_1pct > 0).sum())} draws "
        f"guaranteed 1 %, {int((res.samples_to_1pct > 0).sum())} reach it",
    )
    a5.legend(fontsize=7)
    fig.tight_layout()
    return fig
