"""The counts a Monte Carlo PE map is judged by: Theorem 1 and exact-condition violations."""

import numpy as np

from .condition import SHARPER_STATEMENT
from .families import FAMILIES
from .map_result import PEMap
from .map_settings import numerical_tolerance
from .settle import settle_band

EXACT_STATEMENT = (
    "in every window, the event matrix [h_a; rho_k] has rank n, where rho_k = dh_k / du_k is 1 "
    "for plays moving on the envelope they were on, in (0, 1) for plays starting to move and 0 "
    "for still plays (docs/excitation_condition.md, Theorem 2)"
)


def _counts(rho, pe, sharper, old) -> dict:
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
        "old_sharper_holds_not_pe": int((old & ~pe).sum()),
        "old_sharper_fails_pe": int((~old & pe).sum()),
    }


def summarise(result: PEMap) -> dict:
    """The counts a map is judged by, overall and per family.

    A draw is PE when the map says so (`pe`: its normalised level exceeds
    `numerical_tolerance(dtype)`, or, for a settled map, the rank in exact arithmetic where
    floats cannot decide). Theorem 1 of the paper predicts `theorem_violations` (ρ >= 1 but not
    PE) = 0. The keys `sharper_holds`, `sharper_holds_not_pe` and `sharper_fails_pe` count the
    exact condition ([`exact_condition`][piest_jax.exact_condition], in every window), which is
    necessary and sufficient for PE: without settling, its mismatches with the numerical verdict
    are draws whose levels sit at float64's rounding (see `docs/excitation_condition.md`); a
    settled map decides those exactly. The `old_sharper_*` keys count the earlier sharper
    condition ([`sharper_condition`][], necessary only).

    **Arguments:** `result`, a [`PEMap`][] from [`pe_map`][].

    **Returns:** a JSON-ready dict.
    """
    settings = result.settings
    tol = numerical_tolerance(settings.dtype)
    rho = np.asarray(result.rho)
    pe = np.asarray(result.pe)
    sharper = np.asarray(result.exact)
    old = np.asarray(result.sharper)
    fam = np.asarray(result.family)
    settled = np.zeros_like(pe) if result.settled is None else np.asarray(result.settled)
    total = _counts(rho, pe, sharper, old)
    per_family = {
        FAMILIES[f]: _counts(rho[fam == f], pe[fam == f], sharper[fam == f], old[fam == f]) for f in settings.families
    }
    c1 = np.asarray(result.c1)
    margin = np.asarray(result.margin)
    scale = np.asarray(result.gram_scale)
    # The bound holds up to the rounding of c1 itself, a few eps times the largest eigenvalue.
    violated = margin > c1 + tol * scale
    ratio = c1[sharper & (margin > 0)] / margin[sharper & (margin > 0)]
    measured = np.asarray(result.samples_to_1pct)
    worst = np.asarray(result.worst_samples_to_1pct)
    guaranteed = np.asarray(result.guaranteed_samples_to_1pct)
    both = (worst > 0) & (guaranteed > 0)
    slack = guaranteed[both] / worst[both]
    err, worst_err = np.asarray(result.weight_error), np.asarray(result.worst_error)
    bound = np.asarray(result.guaranteed_error)
    # Each inequality up to the rounding of the errors themselves (relative, a few eps).
    eps = 1e3 * np.finfo(np.asarray(bound).dtype).eps
    return {
        "tolerance": tol,
        "tolerance_meaning": "a draw is PE when min over windows of lambda_min/lambda_max > tolerance",
        **total,
        "theorem_violations_failing_sharper": int(((rho >= 1) & ~pe & ~sharper).sum()),
        "settling": {
            "statement": "draws whose event level is below band, or whose raw-Gram and exact-"
            "condition verdicts disagree, decided by the play outputs' rank in exact arithmetic "
            "(only when the map was run with settle)",
            "done": result.settled is not None,
            "band": settle_band(settings.n_samples, settings.n_plays, settings.dtype),
            "settled": int(np.sum(settled)),
            "settled_pe": int(np.sum(settled & pe)),
            "seconds": float(result.settle_seconds),
        },
        "exact_condition": {
            "statement": EXACT_STATEMENT,
            "violations": total["sharper_holds_not_pe"] + total["sharper_fails_pe"],
            "holds_but_not_pe": total["sharper_holds_not_pe"],
            "fails_but_pe": total["sharper_fails_pe"],
        },
        "margin": {
            "statement": "c1 >= min over windows of lambda_min(D^T D) / (4 L), D the play "
            "increments between the samples where the event row changes (Theorem 4)",
            "violations": int(violated.sum()),
            "c1_over_margin_quantiles": (np.quantile(ratio, [0.0, 0.1, 0.5, 0.9, 1.0]).tolist() if ratio.size else []),
        },
        "convergence": {
            "statement": "the RLS weight error after rls_samples is at most its worst case over "
            "weight vectors, 1/(1 + P0 lambda_min(A)), which is at most the margins' bound "
            "1/(1 + P0 L sum_j c_j margin_j) over disjoint windows j, c_j = dt/(1 + max |h|^2 in "
            "window j)^2; the *_samples_to_1pct times (read every stride samples; -1: not within "
            "rls_samples) are when each falls below 1 % for good",
            "reached_1pct": int((measured > 0).sum()),
            "worst_case_reached_1pct": int((worst > 0).sum()),
            "guaranteed_1pct": int((guaranteed > 0).sum()),
            "violations": int(
                (worst_err > bound * (1 + eps)).sum()
                + (err > worst_err * (1 + eps) + eps).sum()
                + ((guaranteed > 0) & ((worst < 0) | (worst > guaranteed))).sum()
            ),
            "guaranteed_over_worst_time_quantiles": (
                np.quantile(slack, [0.0, 0.1, 0.5, 0.9, 1.0]).tolist() if slack.size else []
            ),
            "bound_over_worst_error_quantiles": np.quantile(
                bound / np.maximum(worst_err, np.finfo(float).tiny), [0.0, 0.1, 0.5, 0.9, 1.0]
            ).tolist(),
        },
        "sharper_condition": {
            "statement": SHARPER_STATEMENT,
            "violations": total["old_sharper_holds_not_pe"] + total["old_sharper_fails_pe"],
            "holds_but_not_pe": total["old_sharper_holds_not_pe"],
            "fails_but_pe": total["old_sharper_fails_pe"],
        },
        "per_family": per_family,
    }
