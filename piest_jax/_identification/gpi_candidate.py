"""The generalized PI as a candidate of `model="auto"`: tried where the output saturates, scored
on the PI candidates' held-out block, and kept only where the record determines it.

A PI with positive weights grows without bound; a material that saturates (a B-H loop, a
magnetostrictive actuator driven hard) needs the output function of the generalized PI. Fitting
it costs several PI fits, so it is tried only where the record asks for it: where a saturating
function y ~ c0 + b v + a tanh((v - m)/s) of a 16-play PI's output v (non-negative weights,
which cannot saturate) leaves at most `GATE` times that PI's error on the fitted samples
(`saturation_gate`; the ratios measured on the project's records are in `docs/fitting.md`).

Its number of plays is chosen as the PI's is: from 2 up, each fitted on the held-out split and
scored on the held-out block, stopping after two in a row that do not improve the score by the
tolerance. The best is fitted on the whole stretch; a fit with an undetermined parameter gives
way to the next best count, and the candidate is chosen only when a determined fit beats the
best model so far (PI, or a chosen Preisach model) by the tolerance. The output
function is monotone and the weights positive, so the chosen model can be inverted. On
stretches of up to `holdout.SHARED_UP_TO` samples, where compiling dominates, every count is
solved padded to the largest (`fit_gpi`'s `pad_plays`) so that all share one compilation, as the
PI candidates are.
"""

import dataclasses

import numpy as np
from scipy import optimize as _optimize

from .._operators.pi import PIOperator
from .fit_gpi import GPIFit, fit_gpi
from .holdout import HOLDOUT, heldout_rmse, holdout_split, padded_plays

GATE = 0.5
GATE_PLAYS = 16
PLAYS = (2, 3, 4, 6, 8)
# The output function's knee: where (in the model output's half-ranges from its centre) and how
# sharp, searched on a grid.
_KNEE_CENTRES = np.linspace(-1.0, 1.0, 9)
_KNEE_SCALES = np.geomspace(0.1, 2.0, 10)


@dataclasses.dataclass(frozen=True)
class GPICandidate:
    """How the generalized-PI candidate of [`identify`][piest_jax.identify]'s `model="auto"`
    fared.

    **Fields:**

    - `gate`: [`saturation_gate`][]'s ratio; the candidate is tried only when it is at most 0.5.
    - `plays`: the play counts tried (empty when the gate kept it from being tried);
      `scores`: their RMSE on the held-out block.
    - `n_plays`: the play count of the determined fit kept, or None.
    - `score`: that fit's held-out RMSE, or None.
    - `undetermined`: for each count fitted on the whole stretch, how many of its parameters the
      record leaves undetermined.
    - `chosen`: whether it was chosen.
    """

    gate: float
    plays: tuple = ()
    scores: tuple = ()
    n_plays: int | None = None
    score: float | None = None
    undetermined: dict = dataclasses.field(default_factory=dict)
    chosen: bool = False

    def to_json(self) -> dict:
        """fit.json's `selection.gpi`."""
        return dataclasses.asdict(self) | {
            "plays": list(self.plays),
            "scores": list(self.scores),
            "undetermined": {str(k): v for k, v in self.undetermined.items()},
        }


def saturation_gate(u, y, used, initial_states=None) -> float:
    """How much of a positive-weight PI's error a saturating output function removes.

    A PI with 16 uniform thresholds on [0, half the input's range) and non-negative weights
    (least squares, with an offset) is fitted on the used samples; its output v cannot
    saturate. Then y ~ c0 + b v + a tanh((v - m)/s) is fitted by least squares for m and s on a
    grid (in v's half-ranges from its centre).

    **Arguments:** `u`, `y`: the record, (T,); `used`: (T,) weights, the samples with `used` > 0
    are the fitted ones; `initial_states`: the plays' states before the first sample (default:
    relaxed at the first input).

    **Returns:** the best saturating function's RMSE over the PI's, on the used samples: near 1
    where nothing saturates (1.0 where the PI leaves no error).
    """
    keep = np.asarray(used) > 0
    u = np.asarray(u, dtype=float)
    half_u = 0.5 * float(np.ptp(u[keep]))
    x0 = u[0] if initial_states is None else initial_states
    r = half_u * np.arange(GATE_PLAYS) / GATE_PLAYS
    H = np.asarray(PIOperator(r, np.ones(GATE_PLAYS), initial_states=x0).regressor(u))[keep]
    yk = np.asarray(y, dtype=float)[keep]
    ones = np.ones((H.shape[0], 1))
    w = _optimize.nnls(np.hstack([H, ones, -ones]), yk)[0]
    v = H @ w[:GATE_PLAYS] + w[GATE_PLAYS] - w[GATE_PLAYS + 1]
    base = float(np.sqrt(np.mean((v - yk) ** 2)))
    half = 0.5 * float(np.ptp(v))
    if not base > 0 or not half > 0:
        return 1.0
    z = (v - 0.5 * (v.max() + v.min())) / half
    best = base
    for m in _KNEE_CENTRES:
        for s in _KNEE_SCALES:
            A = np.column_stack([np.ones_like(z), z, np.tanh((z - m) / s)])
            coef = np.linalg.lstsq(A, yk, rcond=None)[0]
            best = min(best, float(np.sqrt(np.mean((A @ coef - yk) ** 2))))
    return best / base


def gpi_candidate(
    u,
    y,
    mask,
    best: float,
    *,
    tolerance: float = 0.01,
    initial_states=None,
    holdout: float = HOLDOUT,
    n_starts: int = 4,
    key=None,
    max_steps: int = 100,
) -> tuple[GPICandidate, GPIFit | None]:
    """Try a generalized PI where the output saturates, and keep it if it wins.

    **Arguments:**

    - `u`, `y`: the record, (T,) NumPy arrays; `mask`: (T,) 1 on the fitted samples, or None.
    - `best`: the best model's held-out RMSE so far; the generalized PI must beat it by
      `tolerance` (relative).
    - `initial_states`: the plays' states before the first sample, or None (relaxed at the
      first input).
    - `holdout`: the held-out share, as for the PI candidates.
    - `n_starts`, `key`, `max_steps`: as for [`fit_gpi`][piest_jax.fit_gpi].

    **Returns:** the [`GPICandidate`][] and, when chosen, its fit on every fitted sample.
    """
    T = u.shape[0]
    used = np.ones(T) if mask is None else np.asarray(mask, dtype=float)
    gate = saturation_gate(u, y, used, initial_states)
    if not gate <= GATE:
        return GPICandidate(gate), None
    S, split, test = holdout_split(used, holdout)
    options = dict(initial_states=initial_states, n_starts=n_starts, key=key, max_steps=max_steps)
    tried: list[int] = []
    scores: list[float] = []
    lead = 0
    counts = [n for n in PLAYS if 2 * n + 7 <= split.sum()]
    for n in counts:
        pad = padded_plays(n, counts[-1], S)
        held = fit_gpi(u[:S], y[:S], n, mask=split * used[:S], covariance=None, pad_plays=pad, **options)
        tried.append(n)
        scores.append(heldout_rmse(held.model, u, y, S, test))
        if scores[-1] < scores[lead] * (1 - tolerance):
            lead = len(scores) - 1
        if len(scores) - 1 - lead >= 2:
            break  # two in a row without a gain of `tolerance`
    undetermined: dict = {}
    # The smallest count within `tolerance` of the best first, then the others by score.
    for i in sorted(range(len(tried)), key=lambda i: (i != lead, scores[i])):
        if not scores[i] < best * (1 - tolerance):
            continue  # the lead can miss the bar where a count that scores a little better does not
        n = tried[i]
        whole = fit_gpi(u[:S], y[:S], n, mask=used[:S], pad_plays=padded_plays(n, counts[-1], S), **options)
        assert whole.undetermined is not None  # fitted with its covariance
        undetermined[n] = int(np.sum(np.asarray(whole.undetermined)))
        if undetermined[n] == 0:
            fit = whole if S == T else fit_gpi(u, y, n, mask=mask, **options)
            return GPICandidate(gate, tuple(tried), tuple(scores), n, scores[i], undetermined, True), fit
    return GPICandidate(gate, tuple(tried), tuple(scores), undetermined=undetermined), None
