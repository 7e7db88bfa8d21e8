"""Random inputs, threshold sets and initial states for Monte Carlo studies of excitation.

Every draw comes from an explicit PRNG key and is unbatched: one key gives one input (T,), one
threshold vector (n,), one initial-state vector (n,). Batch with `jax.vmap` over keys.

Amplitudes are drawn relative to the largest threshold r_max, log-uniform over
[`AMPLITUDE_RANGE`], so a map covers both sides of Assumption 1 (peak-to-peak >= 2 r_max).
Frequencies are log-uniform over [`FREQUENCY_RANGE`] Hz on a record of `duration` seconds, so some
inputs are slower than a window and some much faster.
"""

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, PRNGKeyArray

from ._custom_types import Signal, States, Thresholds
from ._signals import chirp, triangle

FAMILIES = ("sine", "multisine", "noise", "chirp", "triangle", "decaying", "steps")
AMPLITUDE_RANGE = (0.3, 4.0)
FREQUENCY_RANGE = (0.2, 5.0)


def _log_uniform(key, lo, hi, shape=()):
    return jnp.exp(jax.random.uniform(key, shape, minval=jnp.log(lo), maxval=jnp.log(hi)))


def _common(key, r_max):
    """Amplitude, frequency, offset and phase shared by the periodic families."""
    ka, kf, ko, kp = jax.random.split(key, 4)
    amplitude = r_max * _log_uniform(ka, *AMPLITUDE_RANGE)
    frequency = _log_uniform(kf, *FREQUENCY_RANGE)
    offset = r_max * jax.random.uniform(ko, minval=-1.0, maxval=1.0)
    phase = jax.random.uniform(kp, maxval=2 * jnp.pi)
    return amplitude, frequency, offset, phase


def _sine(key, t, r_max):
    a, f, o, p = _common(key, r_max)
    return o + a * jnp.sin(2 * jnp.pi * f * t + p)


def _multisine(key, t, r_max):
    k0, k1, k2, k3 = jax.random.split(key, 4)
    a, f, o, _ = _common(k0, r_max)
    # Three components whose amplitudes add up to a, so the peak never exceeds o ± a.
    share = jax.random.dirichlet(k1, jnp.ones(3))
    freqs = f * _log_uniform(k2, 1.0, 6.0, (3,)).at[0].set(1.0)
    phases = jax.random.uniform(k3, (3,), maxval=2 * jnp.pi)
    return o + jnp.sum(a * share * jnp.sin(2 * jnp.pi * freqs * t[:, None] + phases), axis=1)


def _noise(key, t, r_max):
    k0, k1 = jax.random.split(key)
    a, f, o, _ = _common(k0, r_max)
    # White noise low-pass filtered by zeroing its spectrum above a cut-off of 2f, then scaled so
    # that its largest excursion is a.
    T = t.shape[0]
    dt = t[1] - t[0]
    spectrum = jnp.fft.rfft(jax.random.normal(k1, (T,), t.dtype))
    cutoff = 2.0 * f
    spectrum = jnp.where(jnp.fft.rfftfreq(T, dt) <= cutoff, spectrum, 0.0)
    x = jnp.fft.irfft(spectrum, n=T)
    x = x - jnp.mean(x)
    return o + a * x / jnp.maximum(jnp.max(jnp.abs(x)), jnp.finfo(t.dtype).tiny)


def _chirp(key, t, r_max):
    k0, k1 = jax.random.split(key)
    a, f, o, _ = _common(k0, r_max)
    f1 = f * _log_uniform(k1, 0.2, 5.0)
    return chirp(t, a, f, f1, o)


def _triangle(key, t, r_max):
    a, f, o, p = _common(key, r_max)
    return triangle(t, a, f, o, p)


def _decaying(key, t, r_max):
    k0, k1 = jax.random.split(key)
    a, f, o, p = _common(k0, r_max)
    # Decay time between 5 % and 50 % of the record: large early, below 2 r_max late.
    tau = (t[-1] - t[0] + (t[1] - t[0])) * jax.random.uniform(k1, minval=0.05, maxval=0.5)
    return o + a * jnp.exp(-(t - t[0]) / tau) * jnp.sin(2 * jnp.pi * f * t + p)


def _steps(key, t, r_max, n_levels: int = 12):
    k0, k1, k2 = jax.random.split(key, 3)
    a, _, o, _ = _common(k0, r_max)
    levels = o + a * jax.random.uniform(k1, (n_levels,), t.dtype, -1.0, 1.0)
    # Random hold times: sorted switching instants over the record.
    span = t[-1] - t[0]
    switches = t[0] + span * jnp.sort(jax.random.uniform(k2, (n_levels - 1,), t.dtype))
    return levels[jnp.searchsorted(switches, t, side="right")]


_BRANCHES = (_sine, _multisine, _noise, _chirp, _triangle, _decaying, _steps)


def draw_input(key: PRNGKeyArray, family, t: Signal, r_max) -> Signal:
    """One random input of the given family on the time grid `t`.

    **Arguments:**

    - `key`: a PRNG key.
    - `family`: index into `FAMILIES` (an integer, may be traced; chosen by `lax.switch`).
    - `t`: the uniform time grid (T,), at least two samples.
    - `r_max`: the largest threshold; amplitudes and offsets scale with it.

    **Returns:** u (T,) in the dtype of `t`.
    """
    if t.ndim != 1 or t.shape[0] < 2:
        raise ValueError(f"`t` must be a time grid of at least two samples, got shape {t.shape}")
    r_max = jnp.asarray(r_max, t.dtype)
    branches = [lambda k, b=b: b(k, t, r_max).astype(t.dtype) for b in _BRANCHES]
    return jax.lax.switch(jnp.asarray(family, jnp.int32), branches, key)


def draw_thresholds(key: PRNGKeyArray, n: int, *, dtype=float) -> Thresholds:
    """A random increasing threshold set (n,).

    r_max is log-uniform on [0.5, 2]; the others are uniform on (0, r_max), sorted; with
    probability 1/2 the first threshold is 0 (the play is then the input itself), as in the paper.

    **Arguments:** `key`; `n` >= 1 plays; `dtype` of the result.

    **Returns:** (n,) thresholds, increasing, the last one r_max.
    """
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise ValueError(f"the number of plays must be a positive whole number, got {n!r}")
    dtype = jnp.dtype(dtype)
    km, ki, kz = jax.random.split(key, 3)
    r_max = _log_uniform(km, 0.5, 2.0).astype(dtype)
    inner = jnp.sort(jax.random.uniform(ki, (n - 1,), dtype)) * r_max
    r = jnp.concatenate([inner, r_max[None]])
    zero_first = jax.random.bernoulli(kz) & (n > 1)
    return r.at[0].set(jnp.where(zero_first, 0.0, r[0]))


def draw_initial_states(key: PRNGKeyArray, r: Thresholds, u0) -> States:
    """Random initial play states, zero with probability 1/2.

    Otherwise each state is uniform on [u0 − r_i, u0 + r_i], the states a play can hold when the
    input is u0 (so the first sample does not jump).

    **Arguments:** `key`; thresholds `r` (n,); `u0`, the input's first sample.

    **Returns:** (n,) initial states.
    """
    kz, ks = jax.random.split(key)
    spread = jax.random.uniform(ks, r.shape, r.dtype, -1.0, 1.0)
    states = u0 + r * spread
    return jnp.where(jax.random.bernoulli(kz), jnp.zeros_like(r), states)


def draw_weights(key: PRNGKeyArray, n: int, *, dtype=float) -> Float[Array, " n"]:
    """Random positive weights, uniform on [0.5, 5] (the paper's weights are 1 to 8)."""
    return jax.random.uniform(key, (n,), jnp.dtype(dtype), 0.5, 5.0)
