"""Choosing the number of plays from the data.

Two criteria. **Held-out error** (the default): every candidate is fitted on the first part of the
record with the last block held out (blocked, not random, so that neighbouring and hence correlated
samples never sit on both sides of the split); the model still runs through the held-out block, so
the plays' states carry over, and its RMSE there is the score. The smallest n whose score is within
`tolerance` of the best is chosen, since a larger model that is not measurably better only fits noise.
This search is [`select_model`][]'s with no lags offered, so the rules below are written once, there.
**BIC**: T ln(MSE) + k ln T on the whole record (T its used samples), k = 2n + 1 parameters
(3n + 1 with fitted initial states), minimised.

Each shape compiles the fit once per record length, about 3-4 s on a CPU. On records of up to
`SHARED_UP_TO` samples, where that dominates, every candidate is padded with inactive plays to
the largest one (`fit_pi`'s `pad_plays`) so that all share one compilation: in float32 on two
cores, candidates 1-10 take 29 s instead of 41 s on 8027 samples and 47 s instead of 56 s on
16054. On longer records the solves dominate and padding only adds work (32108 samples: 73 s
against 68 s), so each candidate keeps its own shape.

A candidate whose fit leaves a parameter undetermined (`PIFit.determined`: the Jacobian's rank,
or a standard error beyond half the parameter's scale) is never chosen, however well it scores:
a parameter the record does not pin down (a play at the top of the input's range that barely
moves, say) makes the model's predictions on other records arbitrary. What the record determines
is judged on all of it, not on the part left before the held-out block: a candidate undetermined
there whose score would improve on the best is fitted again on the whole stretch (held-out block
included) and rejected only if that fit leaves a parameter undetermined too. Rejected
candidates are listed in `rejected`; if the chosen model fitted on the whole record turns out
undetermined, the next candidate in line is taken (BIC, which fits the whole record, the same).

Candidates are tried from the smallest up, and the search stops once `patience` candidates in a
row have not improved the best score (by more than `tolerance` for held-out error); the larger
ones are then not fitted at all.

On a long record the held-out search runs on a stretch of it: the `SELECT_SAMPLES` samples from
the first one used (2^18, 26 s at 10 kHz), split into fitted part and held-out block as above;
the chosen model is then fitted on every sample. Each candidate is a full nonlinear fit, so this
keeps the choice's cost flat in the record's length (at 10^7 samples, seven candidates fitted on
the whole record took eight times the final fit); a stretch of that length holds many input
cycles of any record the choice can judge. BIC, which scores whole-record fits, uses every sample.
"""

import dataclasses

import jax.numpy as jnp
import numpy as np

from .. import _checks
from .._progress import progress
from .fit import PIFit, fit_pi
from .holdout import HOLDOUT, padded_plays
from .model_structure import select_model

CRITERIA = ("holdout", "bic")


@dataclasses.dataclass(frozen=True)
class ModelSize:
    """The result of [`select_plays`][].

    **Fields:**

    - `n_plays`: the chosen number of plays.
    - `candidates`: the numbers tried, smallest first (the search may stop before the largest
      requested); `scores`: their held-out RMSE or BIC, in the same order.
    - `criterion`: `"holdout"` or `"bic"`.
    - `fit`: the chosen model fitted on the whole record (a [`PIFit`][]).
    - `rejected`: the candidates not chosen because a parameter was undetermined.
    - `selection_samples`: the samples the candidates were fitted and scored on (the whole
      record, or its first `SELECT_SAMPLES` used ones; see the module notes).
    """

    n_plays: int
    candidates: tuple
    scores: tuple
    criterion: str
    fit: PIFit
    rejected: tuple = ()
    selection_samples: int | None = None


def select_plays(
    u,
    y,
    candidates=(1, 2, 3, 4, 5, 6, 8, 10),
    *,
    criterion: str = "holdout",
    holdout: float = HOLDOUT,
    tolerance: float = 0.01,
    patience: int | None = 2,
    quiet: bool = True,
    mask=None,
    **fit_kwargs,
) -> ModelSize:
    """Choose the number of plays by held-out error on a blocked split, or by BIC.

    **Arguments:**

    - `u`, `y`: the record, (T,) each.
    - `candidates`: the numbers of plays to try (positive, distinct).
    - `criterion`: `"holdout"` or `"bic"`.
    - `holdout`: the fraction of the record, at its end, held out (criterion `"holdout"`).
    - `tolerance`: relative slack on the best held-out RMSE within which the smallest n wins.
    - `patience`: stop after this many candidates in a row without improvement (None: try all).
    - `quiet`: when False, show a progress bar over the candidates (on a terminal only).
    - `mask`: (T,) 1 on the samples to use, 0 on those that only drive the plays (e.g. a
      start-up transient), as in [`fit_pi`][]; the hold-out block is scored on used samples only.
    - `fit_kwargs`: passed to [`fit_pi`][] (solver, positive_weights, n_starts, key, ...).

    On a record longer than `SELECT_SAMPLES` the held-out search runs on its first stretch
    (`selection_stretch`); the chosen model is fitted on the whole record.

    **Returns:** a [`ModelSize`][]. Raises `ValueError` for an unknown criterion or bad candidates.
    """
    if criterion not in CRITERIA:
        raise ValueError(f"unknown criterion {criterion!r}; choose one of {CRITERIA}")
    cands = tuple(int(c) for c in candidates)
    if not cands or min(cands) < 1 or len(set(cands)) != len(cands):
        raise ValueError(f"`candidates` must be distinct positive numbers, got {candidates}")
    if tolerance < 0:
        raise ValueError(f"`tolerance` must be non-negative, got {tolerance}")
    if patience is not None and (not isinstance(patience, (int, np.integer)) or patience < 1):
        raise ValueError(f"`patience` must be a positive whole number or None, got {patience}")
    cands = tuple(sorted(cands))
    u = _checks.signal(u, "u")
    y = _checks.signal(y, "y")
    T = u.shape[0]
    if criterion == "holdout":
        # One selection rule: the held-out search is `select_model`'s with no lags offered.
        ch = select_model(
            u,
            y,
            1.0,
            cands,
            (0,),
            holdout=holdout,
            tolerance=tolerance,
            patience=patience,
            quiet=quiet,
            mask=mask,
            **fit_kwargs,
        )
        assert isinstance(ch.fit, PIFit)  # `select_model` alone never tries a Preisach model
        return ModelSize(
            ch.n_plays,
            tuple(n for n, _ in ch.candidates),
            ch.scores,
            criterion,
            ch.fit,
            tuple(n for n, _ in ch.rejected),
            ch.selection_samples,
        )

    fits = {}
    scores: list[float] = []
    tried: list[int] = []
    per_play = 3 if fit_kwargs.get("fit_initial_states", False) else 2
    largest = max(cands)
    used = np.ones(T) if mask is None else np.asarray(mask, dtype=float)
    if used.shape != (T,):
        raise ValueError(f"`mask` has shape {used.shape}, expected ({T},)")

    def fit_n(n):
        return fit_pi(u, y, n, pad_plays=padded_plays(n, largest, T), mask=mask, **fit_kwargs)

    n_used = int(np.sum(used > 0))
    since_best = 0
    rejected: set = set()
    bar = progress(cands, desc="plays", quiet=quiet)
    for n in bar:
        f = fits[n] = fit_n(n)
        mse = max(float(f.rmse) ** 2, np.finfo(np.float64).tiny)
        score = n_used * np.log(mse) + (per_play * n + 1) * np.log(n_used)
        eligible = [s for m, s in zip(tried, scores) if m not in rejected]
        better = not eligible or score < min(eligible)
        if not f.determined:
            rejected.add(n)
        tried.append(n)
        scores.append(score)
        since_best = 0 if n not in rejected and better else since_best + 1
        if patience is not None and since_best >= patience:
            break
    if hasattr(bar, "close"):
        bar.close()
    while True:
        chosen = _choose(tried, scores, rejected)
        fit = fits[chosen]
        if fit.determined or len(rejected) >= len(tried) - 1:
            break
        rejected.add(chosen)
    return ModelSize(
        chosen,
        tuple(tried),
        tuple(float(s) for s in scores),
        criterion,
        fit,
        tuple(n for n in tried if n in rejected),
        T,
    )


def _choose(tried, scores, rejected):
    """The candidate with the lowest score among those not rejected (the smaller on a tie); the
    smallest tried when every one is."""
    pairs = [(n, s) for n, s in zip(tried, scores) if n not in rejected]
    if not pairs:
        return min(tried)
    return min(pairs, key=lambda p: (p[1], p[0]))[0]


def rmse(a, b) -> float:
    """Root-mean-square difference of two signals (a convenience for reports)."""
    return float(jnp.sqrt(jnp.mean((jnp.asarray(a) - jnp.asarray(b)) ** 2)))
