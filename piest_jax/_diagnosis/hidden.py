"""Synthetic records with hidden effects: a PI operator plus zero, one or two effects, and noise.

Each effect is drawn in one of several physical forms, deliberately different from the forms the
diagnosis fits (creep as slow exponentials of the output, or a logarithmic law of the output's
or of the input's changes, dynamics of first or second order, asymmetry as an even output map,
quadratic, a power of |v| or a cosh, or an input envelope, saturation as an odd output map,
tanh, Langevin or algebraic, or a tanh of the input, delay applied to the input by
interpolation, drift as a ramp, a warm-up exponential or a slow oscillation, minor-loop
non-congruence as a relay density exponential in the loop centre or with a Gaussian or
Lorentzian bump). Inputs start at rest; noise is white plus sensor quantisation.
"""

import types
import zlib

import jax
import numpy as np

from .. import _checks
from .._data.record import Record
from .basis import N_PLAYS, THRESHOLDS, plays
from .effects import chain, check_names
from .model import lstsq


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


def _pi(u, r, w, x0):
    """The PI operator's output: the plays (thresholds r) weighted by w."""
    return plays(u, r, np.asarray(x0, float)[None])[0] @ w


def generate(effects=(), *, key, n_samples=2000, noise=None, noise_ar: float = 0.0):
    """One synthetic record: PI operator, the named hidden effects, and measurement noise.

    **Arguments:**

    - `effects`: zero, one or two names from `EFFECTS`.
    - `key`: a JAX PRNG key (all randomness derives from it).
    - `n_samples`: the record length.
    - `noise`: the noise std as a fraction of the output range (default: drawn in [0.3 %, 1 %] of
      the range, lowered where needed so the effects' footprint is 2-5x the noise).
    - `noise_ar`: the noise's lag-one autocorrelation φ in [0, 1): coloured (AR(1)) noise
      e_t = φ e_{t-1} + √(1 - φ²) σ ε_t, whose std stays σ; 0 (the default) is white noise.

    **Returns:** `(record, truth)`: a `Record` and a dict with the effects, their drawn forms and
    parameters, and `noise_std` (the true noise std in the record's units).
    """
    check_names(effects)
    if not (isinstance(noise_ar, int | float | np.floating) and 0.0 <= noise_ar < 1.0):
        raise ValueError(f"`noise_ar` must be a number in [0, 1), got {noise_ar!r}")
    rng = _rng(_checks.prng_key(key))
    dt = 1.0 / rng.choice([200.0, 500.0, 1000.0])
    t, u, f0 = _input(rng, n_samples, dt)
    amp = np.abs(u).max()
    n_true = int(rng.integers(3, 12))
    r = np.sort(np.concatenate([[0.0], rng.uniform(0.02, 0.7, n_true - 1)])) * amp
    w = rng.uniform(0.2, 1.0, n_true) * np.exp(-rng.uniform(0, 2) * np.arange(n_true) / n_true)
    w[0] += rng.uniform(0.3, 1.0)
    w *= rng.uniform(0.5, 5.0) / w.sum()
    truth: dict[str, object] = {"effects": list(effects), "forms": {}}
    # What the effects' forms may read: the record's time axis, input and plain PI operator.
    ctx = types.SimpleNamespace(t=t, u=u, dt=dt, f0=f0, amp=amp, r=r, span0=np.ptp(_pi(u, r, w, np.zeros(n_true))))
    effect_seed = int(rng.integers(2**31))

    def simulate(active):
        # The effects' parameters are drawn the same way whichever are active, so a pair's
        # record and each of its single-effect parts share them.
        prng = np.random.default_rng(effect_seed)
        drawn = [(e, e.draw(prng, ctx)) for e in chain(effects)]
        truth["forms"] = {e.name: state["form"] for e, state in drawn}
        on = [(e, state) for e, state in drawn if e.name in active]
        # The signal chain: input side, plays, linear filters, output side.
        signal = types.SimpleNamespace(x0=np.zeros(n_true), u=u, rt=None, g=None)
        for e, state in on:
            e.synth_input(state, ctx, signal)
        g = signal.u if signal.g is None else signal.g
        X = plays(g, r if signal.rt is None else signal.rt, np.asarray(signal.x0, float)[None])[0]
        v = X @ w
        for e, state in on:
            v = v + e.synth_play_terms(state, ctx, X, w)
        for e, state in on:
            v = e.synth_linear(state, ctx, v)
        y = v.copy()
        for e, state in on:
            v, y = e.synth_output(state, ctx, v, y)
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
    y = y + _ar1(rng.normal(0, sig, len(y)), float(noise_ar)) + rng.uniform(-1, 1) * span
    q = sig * rng.uniform(0.1, 0.5)
    y = np.round(y / q) * q  # sensor quantisation
    truth["noise_std"] = float(np.sqrt(sig**2 + q**2 / 12))
    truth["noise_ar"] = float(noise_ar)
    u_off = rng.uniform(-2, 2)
    return Record(t, u + u_off, y, source="hidden-effect generator"), truth


def record_key(key, effects, i: int):
    """The PRNG key of the `i`-th record of a class of hidden-effect records in a study.

    Derived from the class's names, not its place in a list of classes, so a study's records of
    one class stay the same when effects are registered or classes added.

    **Arguments:** `key`, the study's PRNG key; `effects`, the class's hidden effects (a tuple of
    names from `EFFECTS`, empty for effect-free records); `i`, the record's number in its class.

    **Returns:** a PRNG key for [`hidden_effect_record`][piest_jax.hidden_effect_record].
    """
    name = "+".join(effects) or "none"
    return jax.random.fold_in(jax.random.fold_in(key, zlib.crc32(name.encode()) & 0x7FFFFFFF), i)


def _ar1(white, phi: float):
    """White noise of std σ turned into AR(1) noise of lag-one autocorrelation `phi` and std σ,
    stationary from the first sample (unchanged for phi = 0)."""
    if phi == 0.0:
        return white
    e = white * np.sqrt(1.0 - phi**2)
    e[0] = white[0]
    for i in range(1, len(e)):
        e[i] += phi * e[i - 1]
    return e


def _plain_pi_misfit(u, y):
    """RMS of what a plain PI model (dense threshold grid, fitted weights, offset) leaves of y."""
    un = (u - 0.5 * (u.max() + u.min())) / (0.5 * np.ptp(u))
    X = np.column_stack([plays(un, THRESHOLDS, np.full((1, N_PLAYS), un[0]))[0], np.ones(len(u))])
    res = y - X @ lstsq(X, y)
    return float(np.sqrt(np.mean(res**2)))
