"""Where a fitted model and the data disagree: the residual by time window, regime and correlate.

Every place is reported with the residual's RMS there, its ratio to the noise floor, and whether
it is structured (RMS well above the floor, or a correlation beyond what noise would give).
"""

import numpy as np

N_WINDOWS = 10
STRUCTURED_RATIO = 1.5


def _corr(a, b):
    a, b = a - a.mean(), b - b.mean()
    den = np.sqrt((a * a).sum() * (b * b).sum())
    return float((a * b).sum() / den) if den > 0 else 0.0


def _effective_n(r):
    """Samples of a residual that count as independent, from its lag-1 autocorrelation."""
    rho = np.clip(_corr(r[:-1], r[1:]), 0.0, 0.999)
    return max(len(r) * (1 - rho) / (1 + rho), 2.0)


def regimes(t, u, *, startup_fraction=0.1):
    """Boolean masks of the input's regimes.

    **Arguments:** `t`, `u`, the time and input (T,); `startup_fraction`, the share of the record
    counted as start-up when the input has no clear first cycle.

    **Returns:** a dict name -> mask (T,): `start-up` (before the input first reaches 90 % of its
    range from the start), `holds` (input nearly still), `fast` (the fastest quarter of the moving
    samples), `reversals` (near a change of direction), `extremes` (the top and bottom 10 % of the
    input range).
    """
    u = np.asarray(u, float)
    n = len(u)
    span = np.ptp(u) or 1.0
    un = (u - u.min()) / span
    rate = np.abs(np.gradient(un, t))
    moving = rate > 0.02 * (np.percentile(rate, 95) or 1.0)
    far = np.abs(un - un[0]) >= 0.9 * max(np.abs(un - un[0]).max(), 1e-12)
    first = int(np.argmax(far)) if far.any() else int(startup_fraction * n)
    startup = np.arange(n) < max(first, int(0.02 * n))
    fast = moving & (rate >= np.percentile(rate[moving], 75) if moving.any() else False)
    du = np.diff(un)
    sgn = np.sign(du)
    sgn[sgn == 0] = 1
    rev_idx = np.flatnonzero(sgn[1:] != sgn[:-1]) + 1
    reversals = np.zeros(n, bool)
    w = max(n // 200, 1)
    for i in rev_idx:
        reversals[max(i - w, 0) : i + w + 1] = True
    extremes = (un > 0.9) | (un < 0.1)
    return {
        "start-up": startup,
        "holds": ~moving,
        "fast": fast,
        "reversals": reversals,
        "extremes": extremes,
    }


def locate(t, u, y, pred, noise_std: float) -> list[dict]:
    """Report where the residual y - pred is structured and where it is noise.

    **Arguments:**

    - `t`, `u`, `y`: the record (T,).
    - `pred`: the model's output (T,).
    - `noise_std`: the noise floor estimate.

    **Returns:** a list of dicts, each with `kind` (`window`, `regime` or `correlation`), `name`,
    `n_samples`, `rms`, `ratio_to_noise` (windows and regimes) or `correlation` and `limit`
    (correlations), and `structured` (bool). Structured places come first, largest first.
    """
    t, u, y, pred = (np.asarray(a, float) for a in (t, u, y, pred))
    r = y - pred
    floor = max(noise_std, 1e-12 * (np.ptp(y) or 1.0))
    out = []
    edges = np.linspace(0, len(r), N_WINDOWS + 1).astype(int)
    for a, b in zip(edges[:-1], edges[1:]):
        rms = float(np.sqrt(np.mean(r[a:b] ** 2)))
        out.append(
            dict(
                kind="window",
                name=f"t = {t[a]:.4g}..{t[b - 1]:.4g}",
                n_samples=int(b - a),
                rms=rms,
                ratio_to_noise=rms / floor,
                structured=bool(rms > STRUCTURED_RATIO * floor),
            )
        )
    for name, m in regimes(t, u).items():
        if m.sum() < 3:
            continue
        rms = float(np.sqrt(np.mean(r[m] ** 2)))
        out.append(
            dict(
                kind="regime",
                name=name,
                n_samples=int(m.sum()),
                rms=rms,
                ratio_to_noise=rms / floor,
                structured=bool(rms > STRUCTURED_RATIO * floor),
            )
        )
    du = np.gradient(u, t)
    tt = (t - t[0]) / max(t[-1] - t[0], 1e-300)
    lag = max(len(r) // 500, 1)
    feats = {
        "rate du/dt": du,
        "|rate|": np.abs(du),
        "level u": u,
        "level u^2": (u - u.mean()) ** 2,
        "model output": pred,
        "time": tt,
        "time^2": (tt - 0.5) ** 2,
        f"lagged output change y(t-{lag})-y(t)": np.concatenate([np.zeros(lag), pred[:-lag] - pred[lag:]]),
    }
    limit = 3.0 / np.sqrt(_effective_n(r))
    for name, f in feats.items():
        c = _corr(r, f) if np.ptp(f) > 0 else 0.0
        out.append(
            dict(
                kind="correlation",
                name=name,
                correlation=c,
                limit=float(limit),
                structured=bool(abs(c) > limit and abs(c) > 0.1),
            )
        )

    def key(d):
        size = d.get("ratio_to_noise", abs(d.get("correlation", 0.0)) * 10)
        return (not d["structured"], -size)

    return sorted(out, key=key)
