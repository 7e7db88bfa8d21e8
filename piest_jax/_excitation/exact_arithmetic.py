"""Persistent excitation decided in exact arithmetic, where float64 cannot decide it.

Every float is a dyadic rational m·2^e, so the samples, thresholds and initial states of a draw
are integers once scaled by a common power of two, and so are the play outputs: each is an
initial state or a sample plus or minus a threshold, the clamp only compares them. The outputs
are computed exactly on Python integers; the rank of each window's outputs is then taken modulo
two large primes. A rank of n modulo a prime proves full rank over the rationals (a rank mod p
never exceeds the rational rank); a rank below n modulo both primes means rank deficiency unless
both primes divide every n × n minor of the window, which they do not for data that are not
built for it. This settles the draws whose event level (`exact_condition`) sits at float64's
rounding floor, where the float verdict may be wrong either way.
"""

import numpy as np

#: Two primes below 2^31: products of two residues stay below 2^62 in int64.
PRIMES = (2_147_483_647, 2_147_483_629)


def _scaled(*arrays):
    """The arrays as exact Python integers over one common power of two."""
    flat = np.concatenate([np.asarray(a, np.float64).ravel() for a in arrays])
    if not np.all(np.isfinite(flat)):
        raise ValueError("exact arithmetic needs finite values")
    mant, expo = np.frexp(flat)
    ints = (mant * 2.0**53).astype(np.int64)  # exact: 53-bit mantissas
    expo = expo.astype(np.int64) - 53
    low = int(expo[ints != 0].min()) if np.any(ints != 0) else 0
    shift = np.where(ints != 0, expo - low, 0)  # a zero has no exponent to keep
    scaled = np.array([int(i) << int(e) for i, e in zip(ints, shift)], dtype=object)
    out, k = [], 0
    for a in arrays:
        size = np.asarray(a).size
        out.append(scaled[k : k + size].reshape(np.shape(a)))
        k += size
    return out


def exact_play_outputs(u, r, x0):
    """The play outputs of `u` (T,) for thresholds `r` (n,) from states `x0` (n,), exactly, as
    integers over a common power of two (the scale does not change a rank).

    **Returns:** a (T, n) object array of Python integers.
    """
    U, R, X = _scaled(u, r, np.broadcast_to(np.asarray(x0, np.float64), np.shape(r)))
    H = np.empty((U.shape[0], R.shape[0]), dtype=object)
    x = X.copy()
    for k, uk in enumerate(U):
        x = np.maximum(uk - R, np.minimum(uk + R, x))
        H[k] = x
    return H


def _rank_mod(A, p: int) -> int:
    """The rank of the int64 matrix A (entries in [0, p)) modulo the prime p."""
    A = A.copy()
    rows, cols = A.shape
    rank = 0
    for c in range(cols):
        nz = np.flatnonzero(A[rank:, c]) + rank
        if nz.size == 0:
            continue
        piv = nz[0]
        A[[rank, piv]] = A[[piv, rank]]
        inv = pow(int(A[rank, c]), p - 2, p)
        A[rank] = (A[rank] * inv) % p
        below = A[rank + 1 :, c].copy()
        A[rank + 1 :] = (A[rank + 1 :] - (below[:, None] * A[rank]) % p) % p
        rank += 1
        if rank == rows:
            break
    return rank


def _residues(u, r, x0, window: int, stride: int):
    H = exact_play_outputs(u, r, x0)
    T, n = H.shape
    if not (1 <= window <= T and stride >= 1):
        raise ValueError(f"`window` must be in [1, {T}] and `stride` >= 1, got {window}, {stride}")
    residues = [np.array((H % p).tolist(), dtype=np.int64).reshape(T, n) for p in PRIMES]
    return residues, range(0, T - window + 1, stride), n


def _full_rank(residues, a: int, window: int, n: int) -> bool:
    return any(_rank_mod(res[a : a + window], p) == n for res, p in zip(residues, PRIMES))


def exact_window_pe(u, r, x0, window: int, *, stride: int = 1):
    """Per window: do the play outputs have full column rank in exact arithmetic?

    **Arguments:** `u` (T,), `r` (n,), `x0` (n,) as for `piest_jax.play`; `window`, `stride` in
    samples, as for `exact_condition`.

    **Returns:** (windows,) booleans: True is proved (full rank modulo a prime); False means
    rank deficient modulo both `PRIMES` (see the module docstring).
    """
    residues, starts, n = _residues(u, r, x0, window, stride)
    return np.array([_full_rank(residues, a, window, n) for a in starts])


def exact_draw_pe(u, r, x0, window: int, *, stride: int = 1, order=None) -> bool:
    """Is every window full rank in exact arithmetic? `all(exact_window_pe(...))`, stopping at
    the first deficient window.

    **Arguments:** `u`, `r`, `x0`, `window` and `stride` as for [`exact_window_pe`][]; `order`,
    the window indices in the order to try them (default first to last): putting the windows
    most likely deficient first (the lowest float levels) makes a deficient draw cost one or two
    ranks instead of one per window.

    **Returns:** True when every window has full column rank (proved modulo a prime), False when
    one is rank deficient modulo both `PRIMES`.
    """
    residues, starts, n = _residues(u, r, x0, window, stride)
    starts = list(starts)
    order = range(len(starts)) if order is None else [int(i) for i in order]
    if sorted(order) != list(range(len(starts))):
        raise ValueError(f"`order` must list each of the {len(starts)} windows once")
    return all(_full_rank(residues, starts[i], window, n) for i in order)
