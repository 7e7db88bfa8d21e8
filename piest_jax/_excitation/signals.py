"""Deterministic test inputs: sines, multi-sines, triangles, chirps, on a uniform time grid."""

import jax.numpy as jnp
from jaxtyping import Array


def time_grid(duration: float, dt: float) -> Array:
    """Samples 0, dt, 2 dt, ... up to and including `duration` (when it is a multiple of dt).

    **Arguments:** `duration` and `dt`, both positive, in seconds.

    **Returns:** the times, (round(duration / dt) + 1,).
    """
    if dt <= 0 or duration <= 0:
        raise ValueError(f"duration and dt must be positive, got duration={duration}, dt={dt}")
    n = int(round(duration / dt)) + 1
    return jnp.arange(n) * dt


def sine(t, amplitude=1.0, frequency=1.0, offset=0.0, phase=0.0) -> Array:
    """offset + amplitude · sin(2π f t + phase).

    **Arguments:** `t`, the times (T,); `amplitude`, `frequency` (Hz), `offset`, `phase` (rad).

    **Returns:** the signal, (T,).
    """
    return offset + amplitude * jnp.sin(2 * jnp.pi * frequency * t + phase)


def multisine(t, amplitudes, frequencies, phases=None, offset=0.0) -> Array:
    """offset + Σ_k a_k sin(2π f_k t + φ_k).

    **Arguments:** `t`, the times (T,); `amplitudes` and `frequencies` (Hz), one per component;
    `phases` (rad, zero when None); `offset`.

    **Returns:** the signal, (T,).
    """
    a = jnp.atleast_1d(jnp.asarray(amplitudes))
    f = jnp.atleast_1d(jnp.asarray(frequencies))
    if a.shape != f.shape:
        raise ValueError(f"{a.shape[0]} amplitudes but {f.shape[0]} frequencies")
    p = jnp.zeros_like(a) if phases is None else jnp.atleast_1d(jnp.asarray(phases))
    return offset + jnp.sum(a * jnp.sin(2 * jnp.pi * f * t[:, None] + p), axis=1)


def triangle(t, amplitude=1.0, frequency=1.0, offset=0.0, phase=0.0) -> Array:
    """A symmetric triangle wave in [offset - amplitude, offset + amplitude], starting at offset.

    **Arguments:** `t`, the times (T,); `amplitude`, `frequency` (Hz), `offset`, `phase` (rad).

    **Returns:** the signal, (T,).
    """
    s = frequency * t + phase / (2 * jnp.pi) + 0.25
    return offset + amplitude * (4 * jnp.abs(s - jnp.floor(s + 0.5)) - 1)


def chirp(t, amplitude=1.0, f0=0.5, f1=5.0, offset=0.0) -> Array:
    """A linear chirp from f0 to f1 over the span of `t`.

    **Arguments:** `t`, the times (T,); `amplitude`; `f0` and `f1`, the first and last
    frequency (Hz); `offset`.

    **Returns:** the signal, (T,).
    """
    span = t[-1] - t[0]
    k = (f1 - f0) / jnp.where(span > 0, span, 1.0)
    tt = t - t[0]
    return offset + amplitude * jnp.sin(2 * jnp.pi * (f0 * tt + 0.5 * k * tt**2))
