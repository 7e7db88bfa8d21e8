"""The counts a Monte Carlo PE map is judged by: Theorem 1 and sharper-condition violations."""

import numpy as np

from .families import FAMILIES
from .map_settings import MapSettings, numerical_tolerance
from .condition import SHARPER_STATEMENT


def _counts(rho, pe, sharper) -> dict:
    above = rho >= 1
    below = ~above
    return {
        "n": int(rho.size),
        "assumption_holds": int(above.sum()),
        "pe": int(pe.sum()),
        "theorem_violations": int((above & ~pe).sum()),
        "pe_below_assumption": int((below & pe).sum()),
        "pe_fraction_below_assumption": float((below & pe).sum() / max(int(below.sum()), 1)),
        "sharper_holds": int(sharper.sum()),
        "sharper_holds_not_pe": int((sharper & ~pe).sum()),
        "sharper_fails_pe": int((~sharper & pe).sum()),
    }


def summarise(result: dict, settings: MapSettings) -> dict:
    """The counts a map is judged by, overall and per family.

    A draw is PE when its normalised level exceeds `numerical_tolerance(dtype)`. Theorem 1 of
    the paper predicts `theorem_violations` (ρ >= 1 but not PE) = 0. The sharper condition
    ([`sharper_condition`][], in every window) is necessary for PE, so `sharper_fails_pe` must be
    0 up to rounding; `sharper_holds_not_pe` counts the draws where it is not sufficient.

    **Arguments:** `result` from [`pe_map`][]; its `settings`.

    **Returns:** a JSON-ready dict.
    """
    tol = numerical_tolerance(settings.dtype)
    rho = np.asarray(result["rho"])
    pe = np.asarray(result["c1_normalised"]) > tol
    sharper = np.asarray(result["sharper"])
    fam = np.asarray(result["family"])
    total = _counts(rho, pe, sharper)
    per_family = {
        FAMILIES[f]: _counts(rho[fam == f], pe[fam == f], sharper[fam == f])
        for f in settings.families
    }
    return {
        "tolerance": tol,
        "tolerance_meaning": "a draw is PE when min over windows of lambda_min/lambda_max > tolerance",
        **total,
        "theorem_violations_failing_sharper": int(((rho >= 1) & ~pe & ~sharper).sum()),
        "sharper_condition": {
            "statement": SHARPER_STATEMENT,
            "violations": total["sharper_holds_not_pe"] + total["sharper_fails_pe"],
            "holds_but_not_pe": total["sharper_holds_not_pe"],
            "fails_but_pe": total["sharper_fails_pe"],
        },
        "per_family": per_family,
    }
