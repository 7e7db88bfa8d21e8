"""Choosing the model's structure: plain PI or PI + creep, and how many plays and lags.

The same blocked hold-out as [`select_plays`][]: each candidate (n plays, K lags) is fitted on the
first part of the record and scored by its RMSE on the held-out last block, which the model runs
through from the states the first part left it in. A structure whose parameters the fitted part
cannot determine (plays the input barely moves) mostly predicts the held-out block badly and
loses; one that predicts it well all the same (a lag slower than the fitted part, whose weight
over its time constant is all that part shows and all the block needs) may be determined by the
whole stretch, as below. Among candidates within `tolerance` of the best score the smaller
wins, so the record has to show the gain of every added parameter. A candidate whose fit leaves
a parameter undetermined (`PIFit.determined`) is never chosen, as in [`select_plays`][] (judged,
as there, on the whole stretch, held-out block included); nor is one whose whole-record fit does
(the next in line is taken then).

The search is coordinate-wise, to keep the number of fits small (each costs a full nonlinear
fit): (1) the play count of the plain PI model, as [`select_plays`][] does, also when only
models with creep are offered (a lag fitted alongside the plays can take over the part of the
loops that further plays would shape, and the search would stop at one play); (2) the lag count
at that play count among those offered, from the fewest up, stopping after `patience` in a
row that do not improve (an undetermined candidate counts as not improving, but does not end the
search by itself: one lag fitted to a creep of two modes can land on a poorly determined
compromise that two lags resolve). A lag takes over part of what the plays shaped: the play count
chosen without creep can leave a play with almost no weight beside a lag, and its threshold
undetermined. So a candidate (n, K) rejected as undetermined that would have beaten the best
score yet stands aside for (n', K), n' the next play count down, until one is determined; when
the chosen model's whole-record fit is undetermined, the same walk down adds the next smaller
play count with its lags to the line before the next in line is taken. The play count is not
otherwise searched again with the chosen lags: that would double the cost. On records of up to
`SHARED_UP_TO` samples the candidates share compilations by padding with inactive plays and lags
(`fit_pi`'s `pad_plays`, `pad_lags`) in two groups: the plain ones to the largest play count, as
in [`select_plays`][], and those with creep to the chosen play count and the largest lag count.
Padding every candidate to both largest counts, one compilation in all, cost more in solves than
it saved in compiling (float64, two cores, compilation included: Aye's 8027 samples 68 s against
45 s now, the 10^4-sample creep record 46 s against 35 s, 2000 samples 21 s against 16 s; equal
at 500). On a long record the candidates are fitted and scored on its first
stretch, as in [`select_plays`][] (`holdout_split`), and the chosen model on every sample.
"""

import dataclasses

import numpy as np

from .. import _checks
from .._progress import progress
from .fit import PIFit, fit_pi
from .fit_gpi import GPIFit
from .fit_preisach import PreisachFit
from .gpi_candidate import GPICandidate
from .holdout import HOLDOUT, SHARED_UP_TO, holdout_split
from .preisach_candidate import PreisachCandidate

LAG_CANDIDATES = (0, 1, 2, 3)


@dataclasses.dataclass(frozen=True)
class ModelChoice:
    """The result of [`select_model`][].

    **Fields:**

    - `n_plays`, `n_lags`: the chosen counts (the best PI candidate's when a Preisach model
      or a generalized PI was chosen); `structure`: `"pi"`, `"pi+creep"`, `"preisach"` or
      `"gpi"`.
    - `candidates`: the (n_plays, n_lags) pairs tried, in order; `scores`: their held-out RMSE.
    - `fit`: the chosen model fitted on the whole record (a [`PIFit`][], or the
      [`PreisachFit`][] when `preisach.chosen`, the [`GPIFit`][] when `gpi.chosen`).
    - `rejected`: the (n_plays, n_lags) pairs not chosen because a parameter was undetermined.
    - `selection_samples`: the samples the candidates were fitted and scored on (the whole
      record, or its first stretch: `selection_stretch`).
    - `preisach`: how the Preisach candidate of [`identify`][piest_jax.identify]'s
      `model="auto"` fared (a [`PreisachCandidate`][]), or None when it was not tried
      ([`select_model`][] alone never tries it).
    - `gpi`: how the generalized-PI candidate of `model="auto"` fared (a [`GPICandidate`][]),
      or None when it was not tried.
    """

    n_plays: int
    n_lags: int
    candidates: tuple
    scores: tuple
    fit: PIFit | PreisachFit | GPIFit
    rejected: tuple = ()
    selection_samples: int | None = None
    preisach: PreisachCandidate | None = None
    gpi: GPICandidate | None = None

    @property
    def structure(self) -> str:
        """`"pi"`, `"pi+creep"`, `"preisach"` or `"gpi"`."""
        if self.gpi is not None and self.gpi.chosen:
            return "gpi"
        if self.preisach is not None and self.preisach.chosen:
            return "preisach"
        return "pi" if self.n_lags == 0 else "pi+creep"


def select_model(
    u,
    y,
    dt: float,
    plays=(1, 2, 3, 4, 5, 6, 8, 10),
    lags=LAG_CANDIDATES,
    *,
    holdout: float = HOLDOUT,
    tolerance: float = 0.01,
    patience: int | None = 2,
    quiet: bool = True,
    mask=None,
    **fit_kwargs,
) -> ModelChoice:
    """Choose plain PI or PI + creep, the play count and the lag count by blocked hold-out.

    **Arguments:**

    - `u`, `y`: the record, (T,) each; `dt`: its sampling interval.
    - `plays`: play counts to try (positive, distinct; chosen for the plain PI model);
      `lags`: lag counts (>= 0, distinct; 0 is the plain PI model, `(0,)` never adds creep).
    - `holdout`, `tolerance`, `patience`, `quiet`, `mask`: as in [`select_plays`][].
    - `fit_kwargs`: passed to [`fit_pi`][].

    **Returns:** a [`ModelChoice`][]. Raises `ValueError` for bad candidates.
    """
    plays = tuple(sorted(int(c) for c in plays))
    lags = tuple(sorted(int(k) for k in lags))
    if not plays or plays[0] < 1 or len(set(plays)) != len(plays):
        raise ValueError(f"`plays` must be distinct positive numbers, got {plays}")
    if not lags or lags[0] < 0 or len(set(lags)) != len(lags):
        raise ValueError(f"`lags` must be distinct numbers >= 0, got {lags}")
    if tolerance < 0:
        raise ValueError(f"`tolerance` must be non-negative, got {tolerance}")
    if patience is not None and (not isinstance(patience, (int, np.integer)) or patience < 1):
        raise ValueError(f"`patience` must be a positive whole number or None, got {patience}")
    wait = np.inf if patience is None else patience
    u = _checks.signal(u, "u")
    y = _checks.signal(y, "y")
    T = u.shape[0]
    used = np.ones(T) if mask is None else np.asarray(mask, dtype=float)
    if used.shape != (T,):
        raise ValueError(f"`mask` has shape {used.shape}, expected ({T},)")
    S, split, test = holdout_split(used, holdout)
    shared = S <= SHARED_UP_TO
    # The most plays a creep candidate has: the plain model's count once it is chosen.
    creep_plays = max(plays)
    yn = np.asarray(y[:S])
    # Scores closer than this are rounding, not a gain (a noise-free record fits to ~1e-12 of
    # its spread; a flat one to ~1e-16 of its level).
    fitted = yn[used[:S] > 0]
    floor = 1e-8 * max(float(np.std(fitted)), 1e-6 * float(np.max(np.abs(fitted))), 1e-300)
    scores: dict = {}
    rejected: set = set()
    pending: set = set()  # undetermined on the part before the held-out block, not yet on all
    whole: dict = {}  # candidates fitted on the whole record on the way (S == T)
    bar = progress(None, desc="models", quiet=quiet)

    def fit_one(n, k, m, stretch=T):
        if not shared:
            kw: dict = dict(pad_plays=None, pad_lags=None)
        elif k == 0:
            kw = dict(pad_plays=max(plays), pad_lags=None)
        else:
            kw = dict(pad_plays=max(n, creep_plays), pad_lags=max(lags))
        return fit_pi(u[:stretch], y[:stretch], n, n_lags=k, dt=dt, mask=m, **kw, **fit_kwargs)

    def score(n, k):
        if (n, k) not in scores:
            f = fit_one(n, k, split * used[:S], S)
            pred = np.asarray(f(u[:S]))
            scores[(n, k)] = float(np.sqrt(np.mean((pred[test] - yn[test]) ** 2)))
            if not f.determined:
                rejected.add((n, k))
                pending.add((n, k))
            if hasattr(bar, "update"):
                bar.update(1)
        return scores[(n, k)]

    def admit(c, s, best):
        """Whether candidate `c` (score `s`) may be chosen; one undetermined on the part before
        the held-out block that would beat `best` is judged on the whole stretch first (see the
        module notes; one that would not is not worth the fit)."""
        if c in pending and s < best * (1 - tolerance) - floor:
            pending.discard(c)
            f = fit_one(c[0], c[1], mask if S == T else used[:S], S)
            if S == T:
                whole[c] = f
            if f.determined:
                rejected.discard(c)
        return c not in rejected

    def search(values, wait, make):
        """The smallest candidate within tolerance of the best, trying values from the smallest
        up (`make(v, best)` gives the candidate that stands for v, given the best score yet)."""
        tried, best, since = [], np.inf, 0
        for v in values:
            c = make(v, best)
            s = score(*c)
            tried.append((c, s))
            if admit(c, s, best) and s < best * (1 - tolerance) - floor:
                best, since = s, 0
            else:
                since += 1
                if since >= wait:
                    break
        return pick(tried)

    def settle(n, k, best=np.inf):
        """(m, k) with m the most plays, up to n among those offered, that the record determines
        alongside k lags, walking down only while the undetermined candidate would have beaten
        `best`; the last one tried otherwise (see the module notes)."""
        for m in [p for p in plays if p <= n][::-1]:
            s = score(m, k)
            if admit((m, k), s, best) or s >= best * (1 - tolerance) - floor:
                return m, k
        return m, k

    def pick(pairs):
        """The smallest candidate within tolerance of the best not rejected (else the first)."""
        ok = [(c, s) for c, s in pairs if c not in rejected] or pairs[:1]
        best = min(s for _, s in ok)
        return next(c for c, s in ok if s <= best * (1 + tolerance) + floor)

    n, _ = search(plays, wait, lambda v, best: (v, 0))
    creep_plays = n
    n, k = search(lags, wait, lambda v, best: settle(n, v, best))
    while True:
        fit = whole[(n, k)] if (n, k) in whole else fit_one(n, k, mask)
        if fit.determined:
            break
        rejected.add((n, k))
        fewer = [m for m in plays if m < n]
        if fewer:
            settle(fewer[-1], k)
        left = [(c, scores[c]) for c in scores if c not in rejected and c[1] in lags]
        if not left:
            rejected.discard((n, k))  # kept, undetermined, for want of another: not rejected
            break
        n, k = pick(left)
    if hasattr(bar, "close"):
        bar.close()
    cands = tuple(scores)
    return ModelChoice(n, k, cands, tuple(scores[c] for c in cands), fit, tuple(c for c in cands if c in rejected), S)
