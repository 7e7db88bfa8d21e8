"""The blocked hold-out that the model choices score candidates on, and how they share compilations.

The held-out block is the last `HOLDOUT` of the record (or of its first `SELECT_SAMPLES` used
samples on a long record): see [`select_plays`][] and [`select_model`][].
"""

import numpy as np

HOLDOUT = 0.3  # the default held-out fraction
SELECT_SAMPLES = 2**18  # the longest stretch the held-out search fits its candidates on
# Records up to this length pad candidates to shared shapes: compiling dominates there.
SHARED_UP_TO = 2**14


def holdout_mask(T: int, holdout: float) -> np.ndarray:
    """1 on the first samples, 0 on the last `holdout` fraction (a blocked split).

    **Arguments:** `T`, the record length; `holdout`, the held-out fraction in (0, 1).

    **Returns:** float array (T,).
    """
    if not 0 < holdout < 1:
        raise ValueError(f"`holdout` must lie strictly between 0 and 1, got {holdout}")
    n_fit = int(round(T * (1 - holdout)))
    if n_fit < 1 or n_fit >= T:
        raise ValueError(f"a {holdout:g} hold-out of {T} samples leaves an empty block")
    mask = np.zeros(T)
    mask[:n_fit] = 1.0
    return mask


def padded_plays(n: int, largest: int, T: int) -> int:
    """The play count candidate `n` is solved with on a record of `T` samples: the `largest`
    candidate's on records of up to `SHARED_UP_TO` samples, so that all share one compilation."""
    return largest if T <= SHARED_UP_TO else n


def selection_stretch(used: np.ndarray) -> int:
    """The length of the record's first stretch that the held-out search runs on.

    **Arguments:** `used` (T,), 1 on the samples a fit uses (the samples before the first one
    used only drive the plays, so the stretch starts counting there).

    **Returns:** the first used sample's index plus `SELECT_SAMPLES`, at most T.
    """
    T = used.shape[0]
    first = int(np.argmax(used > 0)) if np.any(used > 0) else 0
    return min(T, first + SELECT_SAMPLES)


def heldout_rmse(model, u, y, S: int, test) -> float:
    """RMSE of `model` (run on the stretch `u[:S]`) on the held-out samples `test` (S,) bool."""
    return float(np.sqrt(np.mean((np.asarray(model(u[:S]))[test] - y[:S][test]) ** 2)))


def holdout_split(used: np.ndarray, holdout: float):
    """The stretch the held-out search runs on and its split (see [`select_plays`][]'s notes).

    **Arguments:** `used` (T,), 1 on the samples a fit uses; `holdout`, the held-out fraction.

    **Returns:** `(S, split, test)`: the stretch's length (`selection_stretch`), 1 on its
    fitted part and 0 on its held-out block (S,), and the used samples of that block (S,) bool.
    Raises `ValueError` when the block has no used sample.
    """
    S = selection_stretch(used)
    split = holdout_mask(S, holdout)
    test = (split == 0) & (used[:S] > 0)
    if not test.any():
        raise ValueError("the held-out block has no used samples (all masked out)")
    return S, split, test
