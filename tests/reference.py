"""Plain NumPy loops: the independent references the operators are tested against."""

import numpy as np


def play(u, r, x0=0.0):
    """Play outputs (T, n) by the defining recursion x_t = max(u_t - r, min(u_t + r, x_{t-1}))."""
    u = np.asarray(u, dtype=np.float64)
    r = np.atleast_1d(np.asarray(r, dtype=np.float64))
    x = np.broadcast_to(np.asarray(x0, dtype=np.float64), r.shape).copy()
    out = np.empty((len(u), len(r)))
    for t in range(len(u)):
        for j in range(len(r)):
            lo, hi = u[t] - r[j], u[t] + r[j]
            x[j] = lo if x[j] < lo else (hi if x[j] > hi else x[j])
        out[t] = x
    return out


def stop(u, r, e0=0.0):
    """Stop outputs (T, n) by the direct recursion e_t = clamp(e_{t-1} + u_t - u_{t-1}, -r, r).

    Before the first sample the stop holds `e0` and the input is taken to have been u_0.
    """
    u = np.asarray(u, dtype=np.float64)
    r = np.atleast_1d(np.asarray(r, dtype=np.float64))
    e = np.broadcast_to(np.asarray(e0, dtype=np.float64), r.shape).copy()
    out = np.empty((len(u), len(r)))
    prev = u[0]
    for t in range(len(u)):
        for j in range(len(r)):
            e[j] = min(r[j], max(-r[j], e[j] + u[t] - prev))
        prev = u[t]
        out[t] = e
    return out


def pi(u, r, w, x0=0.0):
    """PI output y_t = Σ_j w_j x_j(t), accumulated sample by sample."""
    H = play(u, r, x0)
    w = np.asarray(w, dtype=np.float64)
    y = np.zeros(len(u))
    for t in range(len(u)):
        acc = 0.0
        for j in range(len(w)):
            acc += w[j] * H[t, j]
        y[t] = acc
    return y


def reachable_states(r, rng, length=40, scale=3.0):
    """Play states some input history produces: the final states of a random walk."""
    u = np.cumsum(rng.normal(0.0, scale, size=length))
    return play(u, r, 0.0)[-1]


def pi_inverse(v, r, w, x0=0.0, iters=200):
    """The input u with PI output v, found sample by sample by bisection on the forward step.

    At each sample the forward output is a continuous, increasing function of u_t (slope w_1 +
    ... + w_i > 0 once plays 1..i move), so bisection on it recovers u_t without using the
    inverse operator's closed form.
    """
    v = np.asarray(v, dtype=np.float64)
    r = np.atleast_1d(np.asarray(r, dtype=np.float64))
    w = np.asarray(w, dtype=np.float64)
    x = np.broadcast_to(np.asarray(x0, dtype=np.float64), r.shape).copy()
    u = np.empty(len(v))

    def forward(ut):
        return float(w @ np.maximum(ut - r, np.minimum(ut + r, x)))

    for t in range(len(v)):
        lo, hi = -1.0, 1.0
        while forward(lo) > v[t]:
            lo *= 2.0
        while forward(hi) < v[t]:
            hi *= 2.0
        for _ in range(iters):
            mid = 0.5 * (lo + hi)
            if mid in (lo, hi):
                break
            if forward(mid) < v[t]:
                lo = mid
            else:
                hi = mid
        u[t] = 0.5 * (lo + hi)
        x = np.maximum(u[t] - r, np.minimum(u[t] + r, x))
    return u


def branches(u, r, x0=0.0):
    """Which side of each play's clamp acts at each sample: -1 lower (u - r), +1 upper (u + r),
    0 hold; and the smallest distance between a held state and a bound (how far from a kink)."""
    u = np.asarray(u, dtype=np.float64)
    r = np.atleast_1d(np.asarray(r, dtype=np.float64))
    x = np.broadcast_to(np.asarray(x0, dtype=np.float64), r.shape).copy()
    codes = np.zeros((len(u), len(r)), dtype=int)
    margin = np.inf
    for t in range(len(u)):
        lo, hi = u[t] - r, u[t] + r
        margin = min(margin, np.min(np.abs(x - lo)), np.min(np.abs(x - hi)))
        codes[t] = np.where(x < lo, -1, np.where(x > hi, 1, 0))
        x = np.clip(x, lo, hi)
    return codes, margin


def exact_play(u, r, x0=0.0):
    """Play outputs in exact rational arithmetic, as a list of rows of `fractions.Fraction`.

    Every float is a dyadic rational, so the samples, thresholds and states are taken exactly and
    the clamp is evaluated without rounding: the outputs of the sampled input as mathematics
    defines them, not as floating point rounds them.
    """
    from fractions import Fraction

    u = [Fraction(float(v)) for v in np.asarray(u, dtype=np.float64)]
    r = [Fraction(float(v)) for v in np.atleast_1d(np.asarray(r, dtype=np.float64))]
    x0 = np.broadcast_to(np.asarray(x0, dtype=np.float64), (len(r),))
    x = [Fraction(float(v)) for v in x0]
    out = []
    for ut in u:
        x = [max(ut - rj, min(ut + rj, xj)) for xj, rj in zip(x, r)]
        out.append(list(x))
    return out


def exact_rank(rows):
    """Rank of a matrix of Fractions (a list of rows) by elimination on integers, exactly."""
    from math import gcd, lcm

    rows = [list(row) for row in rows]
    if not rows:
        return 0
    den = 1
    for row in rows:
        for v in row:
            den = lcm(den, v.denominator)
    A = [[int(v * den) for v in row] for row in rows]
    n = len(A[0])
    rank = 0
    for col in range(n):
        piv = next((i for i in range(rank, len(A)) if A[i][col] != 0), None)
        if piv is None:
            continue
        A[rank], A[piv] = A[piv], A[rank]
        p = A[rank]
        for i in range(rank + 1, len(A)):
            a = A[i][col]
            if a:
                row = [p[col] * A[i][j] - a * p[j] for j in range(n)]
                # Dividing a row by the gcd of its entries keeps the integers small, exactly.
                g = gcd(*row)
                A[i] = [v // g for v in row] if g > 1 else row
        rank += 1
    return rank


def exact_window_pe(u, r, x0, window, stride):
    """Per window: do the exact play outputs of the window have full column rank?"""
    H = exact_play(u, r, x0)
    n = len(H[0])
    return np.array([exact_rank(H[a : a + window]) == n for a in range(0, len(H) - window + 1, stride)])
