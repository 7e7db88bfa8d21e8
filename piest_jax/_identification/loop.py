"""Which way a record's output–input loop runs: counterclockwise (a PI), clockwise (its inverse).

A PI operator with non-negative weights lags its input: rising, the output follows the lower
branch, falling the upper one, so the loop in the (u, y) plane runs counterclockwise and the
signed area ∮ y du is negative. An output that leads its input, as an inverse PI operator's or a
sensor read on the other side of the hysteresis does, runs the loop clockwise (∮ y du > 0), which
no sum of plays with non-negative weights can shape: such a fit collapses to a straight line.

The area is taken on the residual e of the least-squares line y ≈ a + b u (the line's own ∮ y du
is a boundary term, b (u_T² − u_0²)/2, not a loop) by the trapezoidal rule, and scored against
what an output without a loop would give: for e independent of the input's steps, Σ e Δu has
standard deviation std(e) · ‖Δu‖, so the score is a z-value, about N(0, 1) without a loop and in
the tens for a loop measured over a few cycles.
"""

import equinox as eqx
import numpy as np

from .. import _checks

# A loop is called when its area is this many standard deviations from none (a false call on
# white noise is then about one in 10^6; a call costs little: a clockwise record is fitted with
# signed weights, which can shape a counterclockwise loop too).
SCORE_BAR = 5.0


class LoopDirection(eqx.Module):
    """The result of [`loop_direction`][].

    **Fields:**

    - `direction`: `"counterclockwise"` (the output lags, as a PI operator's does),
      `"clockwise"` (the output leads, as an inverse PI operator's does) or `"none"` (no loop
      the record can tell from noise).
    - `score`: the signed area's z-value (negative counterclockwise, positive clockwise).
    """

    direction: str = eqx.field(static=True)
    score: float = eqx.field(static=True)

    def to_json(self) -> dict:
        """`{"direction": ..., "score": ...}`, as fit.json's `loop` holds it."""
        return {"direction": self.direction, "score": self.score}


def loop_direction(u, y) -> LoopDirection:
    """Which way the loop of `y` against `u` runs, from its signed area.

    **Arguments:** `u`, `y`: the record's input and output (T,), finite, T >= 3.

    **Returns:** a [`LoopDirection`][]; `"none"` for an output on a straight line of the input.
    Raises `ValueError` for mismatched, too short or non-finite data.
    """
    u = np.asarray(_checks.finite(_checks.signal(u, "u"), "u"), float)
    y = np.asarray(_checks.finite(_checks.signal(y, "y"), "y"), float)
    if u.shape != y.shape:
        raise ValueError(f"`u` has {u.shape[0]} samples but `y` has {y.shape[0]}")
    if u.shape[0] < 3:
        raise ValueError(f"a loop needs at least 3 samples, got {u.shape[0]}")
    A = np.column_stack([np.ones_like(u), u])
    e = y - A @ np.linalg.lstsq(A, y, rcond=None)[0]
    du = np.diff(u)
    sd = float(np.std(e))
    # A residual at the rounding of the data (an output exactly on a line) is no loop, whatever
    # its sign pattern.
    if not sd > 64 * np.finfo(float).eps * float(np.max(np.abs(y))):
        return LoopDirection("none", 0.0)
    score = float(np.sum(0.5 * (e[1:] + e[:-1]) * du) / (sd * np.sqrt(np.sum(du**2))))
    direction = "clockwise" if score > SCORE_BAR else "counterclockwise" if score < -SCORE_BAR else "none"
    return LoopDirection(direction, score)
