"""A record as the diagnosis sees it: checked, its noise floor, and in normalised units.

Input and output are scaled to [-1, 1] by the identification record's own ranges, and the same
constants are reused for a validation record, so that one fitted model applies to both. The
rate scale, the dominant period and the sampling step set the grids of the effects' parameters.
"""

import dataclasses
import functools

import numpy as np
from scipy import signal as _signal

from .._data.record import DataError, Record
from .._identification.loop import loop_direction
from .._identification.time_constants import shortest_time_constant
from .basis import N_PLAYS, THRESHOLDS, plays, turning_samples

MIN_SAMPLES = 200
N_BLOCKS = 64
N_FOLDS = 4


SMOOTHER = 7


def noise_std(y, step: int = 1) -> float:
    """The noise floor: a robust std of the residual of a local cubic fit over 7 samples.

    The local cubic (Savitzky-Golay) follows the signal, loops and reversals included, so the
    residual is noise: for white noise of std sigma its variance is sigma^2 (1 - h0), with h0 the
    smoother's central weight; the median absolute deviation ignores the few samples at kinks.
    The residual only holds the noise faster than the smoother's span: noise correlated over
    several samples (a filtered sensor, coloured noise) is mostly slower and is missed at
    `step` 1. With `step` m the smoother runs on every m-th sample (each of the m phases, the
    residuals pooled), so it spans 7 m samples and sees the noise up to that time scale.

    **Arguments:** `y`, a sampled signal (T,); `step`, the spacing of the samples the smoother
    runs on.

    **Returns:** the estimated noise std.
    """
    y = np.asarray(y, float)
    step = int(step)
    if step < 1 or len(y) < SMOOTHER * step:
        raise ValueError(f"`step` must be in [1, {len(y) // SMOOTHER}] for {len(y)} samples, got {step}")
    r = np.concatenate(
        [k - _signal.savgol_filter(k, SMOOTHER, 3, mode="interp") for k in (y[i::step] for i in range(step))]
    )
    h0 = _signal.savgol_coeffs(SMOOTHER, 3)[SMOOTHER // 2]
    mad = np.median(np.abs(r - np.median(r)))
    return float(1.4826 * mad / np.sqrt(1 - h0))


def effective_samples(r, max_lag: int) -> float:
    """How many independent samples a residual is worth: n / (1 + 2 sum_k rho_k).

    The autocorrelations rho_k are summed over the initial positive run of lags (up to
    `max_lag`), where they are still above their own sampling noise: white noise gives n,
    AR(1) noise of lag-one correlation phi about n (1 - phi) / (1 + phi).

    **Arguments:** `r`, a residual (T,); `max_lag`, the longest lag summed.

    **Returns:** the effective sample size, at most T.
    """
    r = np.asarray(r, float) - np.mean(r)
    n = len(r)
    c0 = float(r @ r)
    if c0 <= 0:
        return float(n)
    tau = 1.0
    for k in range(1, min(int(max_lag), n - 1) + 1):
        rho = float(r[k:] @ r[:-k]) / c0
        if rho <= 0:
            break
        tau += 2 * rho
    return n / tau


def half_cycle(u, frac: float = 0.05) -> int:
    """The input's half cycle in samples: the median spacing of its reversals.

    The effects the diagnosis names follow the input, so what a model misses is no faster than
    the input's cycles, and a local cubic over half a cycle still follows it: noise faster than
    this span is what the noise floor can tell from a missed effect.

    **Arguments:** `u`, the input (T,); `frac`, the smallest reversal counted, as a share of
    the input's range.

    **Returns:** the half cycle in samples (the record's length when the input reverses less
    than twice).
    """
    u = np.asarray(u, float)
    turns = np.diff(_turns((u - u.min()) / max(np.ptp(u), 1e-300), frac))
    return int(np.median(turns)) if len(turns) else len(u)


# Loops whose reversal points move by less than this share of the input's range are one loop
# traced again: it shows the loop's shape, which a function of the output can give it, and
# nothing of how a loop changes with where it sits.
MIN_SPREAD = 0.1


def reversal_spread(u, frac: float = 0.05) -> float:
    """How far the record's loops move: the larger spread (10th to 90th percentile) of its upper
    and of its lower reversal points, as a share of the input's range (0 when one loop is traced
    again and again; a single different reversal, a start from rest, hardly counts).

    **Arguments:** `u`, the input (T,); `frac`, the smallest reversal counted, as a share of the
    input's range.
    """
    u = np.asarray(u, float)
    un = (u - u.min()) / max(np.ptp(u), 1e-300)
    at = _turns(un, frac)
    if len(at) < 2:
        return 0.0
    v = un[at]
    # The extremes alternate; the first is a maximum when the input then falls.
    first_max = v[0] > v[1]
    highs, lows = (v[0::2], v[1::2]) if first_max else (v[1::2], v[0::2])
    return float(max(np.subtract(*np.percentile(h, [90, 10])) for h in (highs, lows)))


class Prepared:
    """One record in normalised units, with the quantities every regressor needs.

    With `play_u`, `play_rho` and `keep` (from `basis.turning_samples`), the record is a
    sub-sampled one whose plays run on the kept samples plus the turning samples between them,
    so that the play columns equal the full-rate plays at the kept samples.
    """

    def __init__(
        self,
        u,
        y,
        t,
        rate_scale,
        period,
        folds=None,
        *,
        play_u=None,
        play_rho=None,
        keep=None,
        signed=False,
        sample_dt=None,
    ):
        self.u, self.y, self.t = (np.asarray(a, float) for a in (u, y, t))
        self.dt = float(np.median(np.diff(self.t)))
        # The sampling interval of the full-rate record this one was sub-sampled from.
        self.sample_dt = self.dt if sample_dt is None else float(sample_dt)
        self.s = (self.t - self.t[0]) / max(self.t[-1] - self.t[0], 1e-300)
        self.rho = np.abs(np.gradient(self.u, self.t)) / rate_scale
        self.period = period
        self.folds = folds
        self.play_u = self.u if play_u is None else np.asarray(play_u, float)
        self.play_rho = self.rho if play_rho is None else np.asarray(play_rho, float)
        self.keep = keep
        # The play weights are signed (`Scaling.signed_plays`), not kept >= 0.
        self.signed = bool(signed)
        self._plain = None
        # What the diagnosis computes again and again on this record, kept for the record's
        # life: the search's scores of configurations (`diagnose._fit_many`), creep's lags of
        # the input (`effects/creep.py`). Its keys leave out the record's arrays: a record
        # whose arrays change is a new `Prepared` (`prepared`), never this one changed.
        self.cache: dict = {}

    # What the effects' grids ask of the input in every round, computed once.

    @functools.cached_property
    def spread(self) -> float:
        """How far the record's loops move (`reversal_spread` of the input)."""
        return reversal_spread(self.u)

    @property
    def one_loop(self) -> bool:
        """Whether the record traces one loop again and again (`spread` < `MIN_SPREAD`): an
        effect that would claim how loops elsewhere differ from it (an input envelope, a
        density that depends on a loop's centre) is then undetermined by the record."""
        return self.spread < MIN_SPREAD

    @functools.cached_property
    def shortest_lag(self) -> float:
        """The fastest creep lag `piest fit` allows on this record (`shortest_time_constant`,
        its floor counted in samples of the full-rate record), in seconds."""
        return shortest_time_constant(self.u, self.dt, sample_dt=self.sample_dt)

    def plain_plays(self):
        """The plays on the threshold grid from rest at the first sample (computed once)."""
        if self._plain is None:
            self._plain = plays(self.play_u, THRESHOLDS, np.full((1, N_PLAYS), self.u[0]), self.keep)[0]
        return self._plain


@dataclasses.dataclass(frozen=True)
class Scaling:
    """The normalisation of one identification record, reused for validation records."""

    u_mid: float
    u_half: float
    y_mid: float
    y_half: float
    rate_scale: float
    omega_ref: float
    period: float
    delay_unit: float
    # The record's loop runs clockwise (the output leads the input, as an inverse PI's does): the
    # plays' weights are then signed, since non-negative ones shape counterclockwise loops only.
    signed_plays: bool = False


def check_record(rec: Record, *, validation: bool = False) -> None:
    """Refuse records the diagnosis cannot use, with a message naming the problem.

    **Arguments:** `rec`, a `Record`; `validation`: it is only predicted (a `--validate`
    record), so a short record or one sweep is as good a target as any.

    **Returns:** nothing; raises `DataError` for NaN/inf, time that does not increase, a
    constant output, and (unless `validation`) too few samples or an input with no excitation.
    """
    src = rec.source
    if rec.n_samples < MIN_SAMPLES and not validation:
        raise DataError(f"{src}: too short: {rec.n_samples} samples, the diagnosis needs {MIN_SAMPLES}")
    for name, col in (("t", rec.t), ("u", rec.u), ("y", rec.y)):
        bad = ~np.isfinite(col)
        if bad.any():
            raise DataError(
                f"{src}: column `{name}` has {int(bad.sum())} NaN/inf values "
                f"(first at row {int(np.argmax(bad))}); remove or fill them"
            )
    if not np.all(np.diff(rec.t) > 0):
        raise DataError(f"{src}: time stamps are not strictly increasing")
    if np.ptp(rec.y) <= 1e-9 * np.max(np.abs(rec.y)):
        # Nothing to model; on a validation record the fit percentage would divide by zero.
        raise DataError(f"{src}: constant output: y does not change, there is nothing to model")
    if validation:
        return
    du = np.ptp(rec.u)
    if du <= 1e-9 * np.max(np.abs(rec.u)):
        raise DataError(f"{src}: no excitation: the input u is constant, nothing can be identified")
    un = (rec.u - rec.u.min()) / du
    turns = _reversals(un)
    if turns < 2:
        how = "never reverses direction" if turns == 0 else "reverses direction only once"
        raise DataError(
            f"{src}: no excitation: the input {how}, so no hysteresis loop is traced; record at "
            "least one rise and fall after the first sweep"
        )


def _reversals(un, frac=0.05):
    """Direction changes of a signal in [0, 1] larger than `frac` (a hysteresis counter)."""
    return len(_turns(un[:: max(1, len(un) // 20000)], frac))


def _turns(un, frac):
    """The samples where a signal in [0, 1] turns back by more than `frac` (its extremes)."""
    out, ext, at, direction = [], un[0], 0, 0
    for i, v in enumerate(un):
        if direction == 0:
            if abs(v - ext) > frac:
                direction, ext, at = (1 if v > ext else -1), v, i
        elif direction * (v - ext) > 0:
            ext, at = v, i
        elif direction * (ext - v) > frac:
            out.append(at)
            direction, ext, at = -direction, v, i
    return out


def scaling_of(rec: Record, loop=None) -> Scaling:
    """The normalisation constants of an identification record.

    **Arguments:** `rec`, the record; `loop`, its `loop_direction` when the caller has it
    (otherwise computed here).

    **Returns:** a `Scaling`.
    """
    u_mid, u_half = 0.5 * (rec.u.max() + rec.u.min()), 0.5 * np.ptp(rec.u)
    y_mid, y_half = 0.5 * (rec.y.max() + rec.y.min()), 0.5 * np.ptp(rec.y)
    rate = np.abs(np.gradient((rec.u - u_mid) / u_half, rec.t))
    rate_scale = float(np.percentile(rate, 90)) or float(rate.max())
    duration = float(rec.t[-1] - rec.t[0])
    f_dom = max(_reversals((rec.u - rec.u.min()) / np.ptp(rec.u)) / 2, 1.0) / duration
    loop = loop_direction(rec.u, rec.y) if loop is None else loop
    clockwise = loop.direction == "clockwise"
    return Scaling(
        float(u_mid),
        float(u_half),
        float(y_mid),
        float(y_half),
        rate_scale,
        float(2 * np.pi * 10 * f_dom),
        float(1 / f_dom),
        rec.dt,
        clockwise,
    )


def prepared(rec: Record, sc: Scaling, *, step: int = 1, folds: bool = False) -> Prepared:
    """A record in the identification record's normalised units, optionally sub-sampled.

    **Arguments:** `rec`; `sc`, the identification record's `Scaling`; `step`, keep every
    `step`-th sample; `folds`, assign the samples to interleaved cross-validation folds of
    contiguous blocks (the first block to none: fold -1, fitted in every fold).

    **Returns:** a `Prepared`.
    """
    u_full = (rec.u - sc.u_mid) / sc.u_half
    u = u_full[::step]
    y = ((rec.y - sc.y_mid) / sc.y_half)[::step]
    t = rec.t[::step]
    f = None
    if folds:
        blocks = np.minimum((np.arange(len(u)) * N_BLOCKS) // len(u), N_BLOCKS - 1)
        # The first block is always fitted, never held out: how a model continues the record's
        # start, which the unrecorded past sets, says little of how it predicts the rest, and
        # one start transient far above the noise would outweigh every other block in the score.
        f = np.where(blocks == 0, -1, blocks % N_FOLDS)
    if step == 1:
        return Prepared(u, y, t, sc.rate_scale, sc.period, f, signed=sc.signed_plays)
    # The plays see every turning point of the full-rate input, not only the kept samples: a
    # sub-sampled sine's peaks fall between samples, and plays run on it would miss them.
    index, keep = turning_samples(u_full, step)
    rho = np.abs(np.gradient(u_full, rec.t))[index] / sc.rate_scale
    return Prepared(
        u,
        y,
        t,
        sc.rate_scale,
        sc.period,
        f,
        play_u=u_full[index],
        play_rho=rho,
        keep=keep,
        signed=sc.signed_plays,
        sample_dt=rec.dt,
    )
