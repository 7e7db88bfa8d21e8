"""Synthetic records with hidden effects: a PI operator plus zero, one or two effects, and noise.

Each effect is drawn in one of several physical forms, deliberately different from the forms the
diagnosis fits (creep as slow exponentials or as a logarithmic law, dynamics of first or second
order, asymmetry as output saturation, a quadratic output, an input envelope or an exponential
characteristic, delay applied to the input by interpolation, drift as a ramp, a warm-up
exponential or a slow oscillation). Inputs start at rest; noise is white plus sensor quantisation.
"""

import jax
import numpy as np

from .._data.record import Record
from .effects import EFFECTS, N_PLAYS, THRESHOLDS, _lstsq, plays


def _rng(key):
    seed = np.asarray(jax.random.randint(key, (), 0, 2**31 - 1)).item()
    return np.random.default_rng(seed)


def _input(rng, n, dt):
    """Amplitude-varying sweeps of two frequencies with pauses, starting and ending at rest."""
    t = np.arange(n) * dt
    dur = t[-1]
    f0 = rng.uniform(6, 12) / dur
    rest = int(rng.uniform(0.03, 0.06) * n)
    tt = np.clip(t - t[rest], 0, None)
    env = 0.55 + 0.45 * np.sin(2 * np.pi * tt / (dur * rng.uniform(0.6, 1.2)) + rng.uniform(0, 1)) ** 2
    u = env * np.sin(2 * np.pi * f0 * tt) + rng.uniform(0.1, 0.3) * np.sin(2 * np.pi * f0 * rng.uniform(2.2, 3.7) * tt)
    # A ramp-in from rest and two pauses (holds) where slow effects show.
    ramp = np.clip(tt / (0.5 / f0), 0, 1)
    u = u * ramp
    for c in rng.uniform(0.3, 0.85, size=2):
        i0, i1 = int(c * n), int(c * n) + int(rng.uniform(0.03, 0.06) * n)
        u[i0:i1] = u[i0]
        u[i1:] = u[i1:] - u[i1] + u[i0]
    u[:rest] = 0.0
    return t, rng.uniform(1, 10) * u, f0


def _pi(u, r, w, x0, rt=None):
    x = np.array(x0, float)
    out = np.empty((len(u), len(r)))
    for i, ui in enumerate(u):
        ri = r if rt is None else rt[i]
        x = np.maximum(ui - ri, np.minimum(ui + ri, x))
        out[i] = x
    return out @ w


def _lowpass(v, a):
    out = np.empty_like(v)
    s = v[0]
    for i, vi in enumerate(v):
        s = a * s + (1 - a) * vi
        out[i] = s
    return out


def _second_order(v, wn, zeta, dt):
    sub = max(int(np.ceil(wn * dt / 0.05)), 1)
    h = dt / sub
    x, xd = v[0], 0.0
    out = np.empty_like(v)
    prev = v[0]
    for i, vi in enumerate(v):
        for k in range(sub):  # semi-implicit Euler on a fine grid, input interpolated linearly
            vk = prev + (k + 1) / sub * (vi - prev)
            xd += h * (wn**2 * (vk - x) - 2 * zeta * wn * xd)
            x += h * xd
        out[i] = x
        prev = vi
    return out


def generate(effects=(), *, key, n_samples=2000, noise=None):
    """One synthetic record: PI operator, the named hidden effects, and measurement noise.

    **Arguments:**

    - `effects`: zero, one or two names from `EFFECTS`.
    - `key`: a JAX PRNG key (all randomness derives from it).
    - `n_samples`: the record length.
    - `noise`: the noise std as a fraction of the output range (default: drawn in [0.3 %, 1 %] of
      the range, lowered where needed so the effects' footprint is 2-5x the noise).

    **Returns:** `(record, truth)`: a `Record` and a dict with the effects, their drawn forms and
    parameters, and `noise_std` (the true noise std in the record's units).
    """
    for e in effects:
        if e not in EFFECTS:
            raise ValueError(f"unknown effect {e!r}; choose from {EFFECTS}")
    rng = _rng(key)
    dt = 1.0 / rng.choice([200.0, 500.0, 1000.0])
    t, u, f0 = _input(rng, n_samples, dt)
    amp = np.abs(u).max()
    n_true = int(rng.integers(3, 12))
    r = np.sort(np.concatenate([[0.0], rng.uniform(0.02, 0.7, n_true - 1)])) * amp
    w = rng.uniform(0.2, 1.0, n_true) * np.exp(-rng.uniform(0, 2) * np.arange(n_true) / n_true)
    w[0] += rng.uniform(0.3, 1.0)
    w *= rng.uniform(0.5, 5.0) / w.sum()
    x0 = np.zeros(n_true)
    truth = {"effects": list(effects), "forms": {}}
    form = truth["forms"]
    span0 = np.ptp(_pi(u, r, w, x0))

    effect_seed = int(rng.integers(2**31))

    def simulate(active):
        # The effects' parameters are drawn the same way whichever are active, so a pair's
        # record and each of its single-effect parts share them.
        prng = np.random.default_rng(effect_seed)
        form.clear()
        x0, rt, uu = np.zeros(n_true), None, u
        if "initial_state" in effects:
            # Memory of an earlier excursion beyond what this record reaches first.
            top = prng.choice([-1, 1]) * amp * prng.uniform(0.9, 1.3)
            pre = np.concatenate([np.linspace(0, top, 50), np.linspace(top, 0, 50)])
            if "initial_state" in active:
                x0 = _pi_states(pre, r)
            form["initial_state"] = "states left by an earlier excursion"
        if "delay" in effects:
            d = prng.uniform(1.5, 8.0) * dt
            if "delay" in active:
                uu = np.interp(t - d, t, u, left=u[0])
            form["delay"] = f"input delayed by {d / dt:.2f} samples"
        if "rate_dependence" in effects:
            rate = np.abs(np.gradient(u, t))
            rate = rate / np.percentile(rate, 95)
            b = prng.uniform(0.5, 1.2)
            if prng.random() < 0.5:
                rt_ = r[None, :] * (1 + b * rate[:, None])
                form["rate_dependence"] = "thresholds proportional to 1 + b|du/dt|"
            else:
                rt_ = r[None, :] + b * 0.15 * amp * np.sqrt(rate)[:, None]
                form["rate_dependence"] = "thresholds grow with sqrt|du/dt|"
            if "rate_dependence" in active:
                rt = rt_
        g = uu
        asym_form = None
        if "asymmetry" in effects:
            asym_form = str(prng.choice(["saturation", "quadratic", "envelope", "exponential"]))
            form["asymmetry"] = asym_form
            k_asym = prng.uniform(0.25, 0.5) * prng.choice([-1, 1])
            if asym_form == "envelope" and "asymmetry" in active:
                g = uu + k_asym * uu**2 / amp
            if "asymmetry" not in active:
                asym_form = None
        v = _pi(g, r, w, x0, rt)
        if "linear_dynamics" in effects:
            wn = 2 * np.pi * f0 * prng.uniform(3, 8)
            zeta = prng.uniform(0.3, 0.9)
            if prng.random() < 0.5:
                if "linear_dynamics" in active:
                    v = _lowpass(v, np.exp(-dt * wn))
                form["linear_dynamics"] = f"first order, tau = {1 / wn:.3g} s"
            else:
                if "linear_dynamics" in active:
                    v = _second_order(v, wn, zeta, dt)
                form["linear_dynamics"] = f"second order, wn = {wn:.3g} rad/s, zeta = {zeta:.2f}"
        if asym_form is not None and asym_form != "envelope":
            m = 0.5 * (v.max() + v.min())
            h = 0.5 * np.ptp(v)
            z = (v - m) / h
            if asym_form == "saturation":
                k = 0.8 + 1.4 * abs(k_asym)
                z = np.tanh(k * z) / np.tanh(k)
            elif asym_form == "quadratic":
                z = z + 0.5 * k_asym * (z**2 - 0.5)
            else:
                k = (0.5 + 2 * abs(k_asym)) * np.sign(k_asym)
                z = np.expm1(k * z) / k
            v = m + h * z
        y = v.copy()
        if "creep" in effects:
            c = prng.uniform(0.08, 0.2)
            taus = t[-1] * np.array([prng.uniform(0.01, 0.04), prng.uniform(0.1, 0.4)])
            t0 = prng.uniform(0.2, 1.0) / max(f0, 1e-9) / 10
            if prng.random() < 0.5:
                if "creep" in active:
                    y = y + c * sum(_lowpass(v, np.exp(-dt / tau)) - v for tau in taus) * 0.5
                form["creep"] = "two slow exponential modes"
            else:
                # Logarithmic creep: every output change keeps growing as log(1 + t/t0).
                kern = np.log1p(np.arange(len(t)) * dt / t0)
                kern = kern / kern[-1]
                if "creep" in active:
                    y = y + c * 1.5 * np.convolve(np.diff(v, prepend=v[0]), kern)[: len(t)]
                form["creep"] = "logarithmic, log(1 + t/t0)"
        if "offset_drift" in effects:
            d = prng.uniform(0.04, 0.1) * span0
            kind = str(prng.choice(["ramp", "warm-up", "oscillation"]))
            s = t / t[-1]
            shape = {"ramp": s, "warm-up": 1 - np.exp(-s / prng.uniform(0.1, 0.3)),
                     "oscillation": np.sin(2 * np.pi * s * prng.uniform(0.5, 1.5) + prng.uniform(0, 6))}[kind]
            if "offset_drift" in active:
                y = y + d * shape * prng.choice([-1, 1])
            form["offset_drift"] = kind
        return y

    y = simulate(effects)
    span = np.ptp(y)
    sig = span * (rng.uniform(0.003, 0.01) if noise is None else noise)
    if effects and noise is None:
        # A hidden effect is one the data can show: its footprint, what a plain PI fit to the
        # noise-free output leaves, is kept at 2-5x the noise (the noise at least 0.1 % of span).
        # With two effects, each one's own footprint counts, so that neither is invisible.
        foot = min(_plain_pi_misfit(u, simulate((e,))) for e in effects) if len(effects) > 1 else _plain_pi_misfit(u, y)
        sig = max(min(sig, foot / rng.uniform(2.0, 5.0)), 1e-3 * span)
    y = y + rng.normal(0, sig, len(y)) + rng.uniform(-1, 1) * span
    q = sig * rng.uniform(0.1, 0.5)
    y = np.round(y / q) * q  # sensor quantisation
    truth["noise_std"] = float(np.sqrt(sig**2 + q**2 / 12))
    u_off = rng.uniform(-2, 2)
    return Record(t, u + u_off, y, source="hidden-effect generator"), truth


def _plain_pi_misfit(u, y):
    """RMS of what a plain PI model (dense threshold grid, fitted weights, offset) leaves of y."""
    un = (u - 0.5 * (u.max() + u.min())) / (0.5 * np.ptp(u))
    X = np.column_stack([plays(un, THRESHOLDS, np.full((1, N_PLAYS), un[0]))[0], np.ones(len(u))])
    res = y - X @ _lstsq(X, y)
    return float(np.sqrt(np.mean(res**2)))


def _pi_states(u, r):
    x = np.zeros(len(r))
    for ui in u:
        x = np.maximum(ui - r, np.minimum(ui + r, x))
    return x
