"""The Preisach model as a candidate of `model="auto"`: scored on the PI candidates' held-out
block, and kept only where the record determines its density.

A Preisach density is known only where the input's reversals switch relays apart. A record that
repeats one loop shows it through the two branches alone, the smoothness penalty fills in the
rest of the triangle, and a held-out block of the same record revisits the same reversals, so
it cannot see the guess: on the Aye piezo run the 16 x 16 model scores 0.28 on the held-out
block against PI with creep's 0.35, and predicts the other run at 1.79 against 0.53, with 93 of
its 144 cells undetermined (`experiments/preisach_determined.py`). So the candidate obeys the
rule the PI candidates obey: a model with an undetermined parameter (`PreisachFit.undetermined`,
judged on the whole stretch, held-out block included) is never chosen. The rule is strict: a
record whose reversals leave a few relays unseparated keeps PI even where a Preisach model would
predict well (the experiments' synthetic plant on 50 random reversals). The density is kept
non-negative, so the chosen model can be inverted.
"""

import dataclasses

import numpy as np

from .fit_preisach import PreisachFit, fit_preisach
from .holdout import HOLDOUT, heldout_rmse, holdout_split

GRID = (16, 16)  # half-widths x centres: the input range resolved in sixteenths, as a 16-play PI


@dataclasses.dataclass(frozen=True)
class PreisachCandidate:
    """How the Preisach candidate of [`identify`][piest_jax.identify]'s `model="auto"` fared.

    **Fields:**

    - `grid`: its (half-widths, centres).
    - `score`: its RMSE on the held-out block the PI candidates were scored on.
    - `undetermined`: how many of its parameters the record leaves undetermined, judged on the
      selection's whole stretch; None when its score did not beat the best PI candidate's (it
      was not fitted on the whole stretch then).
    - `chosen`: whether it was chosen.
    """

    grid: tuple
    score: float
    undetermined: int | None
    chosen: bool

    def to_json(self) -> dict:
        """fit.json's `selection.preisach`."""
        return dataclasses.asdict(self) | {"grid": list(self.grid)}


def preisach_candidate(
    u, y, mask, best: float, *, tolerance: float = 0.01, initial_states=None, holdout: float = HOLDOUT
) -> tuple[PreisachCandidate, PreisachFit | None]:
    """Score a non-negative Preisach model on the held-out block and keep it if it wins.

    **Arguments:**

    - `u`, `y`: the record, (T,) NumPy arrays; `mask`: (T,) 1 on the fitted samples, or None.
    - `best`: the best PI candidate's held-out RMSE; the Preisach model must beat it by the
      same margin as a PI candidate beats another ([`select_model`][]'s `tolerance`).
    - `initial_states`: the plays' states before the first sample, or None (relaxed at the
      first input).
    - `holdout`: the held-out share, as for the PI candidates.

    **Returns:** the [`PreisachCandidate`][] and, when chosen, its fit on every fitted sample.
    """
    T = u.shape[0]
    used = np.ones(T) if mask is None else np.asarray(mask, dtype=float)
    S, split, test = holdout_split(used, holdout)
    options = dict(n_widths=GRID[0], n_centres=GRID[1], monotone=True, initial_states=initial_states)
    held = fit_preisach(u[:S], y[:S], mask=split * used[:S], covariance=None, **options)
    score = heldout_rmse(held.model, u, y, S, test)
    if not score < best * (1 - tolerance):
        return PreisachCandidate(GRID, score, None, False), None
    whole = fit_preisach(u[:S], y[:S], mask=used[:S], **options)
    assert whole.undetermined is not None  # fitted with its covariance
    undetermined = int(np.sum(np.asarray(whole.undetermined)))
    if undetermined:
        return PreisachCandidate(GRID, score, undetermined, False), None
    fit = whole if S == T else fit_preisach(u, y, mask=mask, **options)
    return PreisachCandidate(GRID, score, undetermined, True), fit
