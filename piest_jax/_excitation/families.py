"""Random inputs, threshold sets and initial states for Monte Carlo studies of excitation.

Every draw comes from an explicit PRNG key and is unbatched: one key and a family give one input
(T,), one threshold vector (n,), one initial-state vector (n,), one weight vector (n,). Batch with
`jax.vmap` over keys; the family is static (it picks the generator), so a batch mixing families
runs one vmap per family instead of evaluating every generator for every draw.

Amplitudes are drawn relative to the largest threshold r_max, log-uniform over
[`AMPLITUDE_RANGE`], so a map covers both sides of Assumption 1 (peak-to-peak >= 2 r_max).
Frequencies are log-uniform over [`FREQUENCY_RANGE`] Hz on a record of `duration` seconds, so some
inputs are slower than a window and some much faster.
"""

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, PRNGKeyArray

from .._custom_types import Signal, States, Thresholds
from .signals import chirp, triangle

FAMILIES = (
    "sine", "multisine", "noise", "chirp", "triangle", "decaying", "steps",
    "ramp", "touch", "nested",
)
# The families a map draws from unless told otherwise; the last three are adversarial cases for
# the exact excitation condition (docs/excitation_condition.md) and are asked for by name.
DEFAULT_FAMILIES = FAMILIES[:7]
AMPLITUDE_RANGE = (0.3, 4.0)
FREQUENCY_RANGE = (0.2, 5.0)


def _log_uniform(v, lo, hi):
    """Map uniform draws v in [0, 1) to a log-uniform law on [lo, hi]."""
    return jnp.exp(jnp.log(lo) + v * (jnp.log(hi) - jnp.log(lo)))


# Every random number of a case comes from ONE call of the generator: the family's parameters,
# then the thresholds, initial states and weights, each reading its own slice of one uniform
# vector. Each separate call would be a separate unrolled hash in the compiled program, and
# compiling those dominates a small map.


def _common(v, r_max):
    """Amplitude, frequency, offset and phase shared by the periodic families, from v[:4]."""
    amplitude = r_max * _log_uniform(v[0], *AMPLITUDE_RANGE)
    frequency = _log_uniform(v[1], *FREQUENCY_RANGE)
    offset = r_max * (2 * v[2] - 1)
    phase = 2 * jnp.pi * v[3]
    return amplitude, frequency, offset, phase


def _sine(v, t, r_max):
    a, f, o, p = _common(v, r_max)
    return o + a * jnp.sin(2 * jnp.pi * f * t + p)


def _multisine(v, t, r_max):
    a, f, o, _ = _common(v, r_max)
    # Three components whose amplitudes add up to a, so the peak never exceeds o ± a. Normalised
    # unit exponentials are a uniform draw on the simplex (a flat Dirichlet).
    e = -jnp.log1p(-v[4:7])
    share = e / jnp.sum(e)
    freqs = f * _log_uniform(v[7:10], 1.0, 6.0).at[0].set(1.0)
    phases = 2 * jnp.pi * v[10:13]
    return o + jnp.sum(a * share * jnp.sin(2 * jnp.pi * freqs * t[:, None] + phases), axis=1)


def _noise(v, t, r_max):
    a, f, o, _ = _common(v, r_max)
    # Band-limited noise as a random-phase multisine: a flat spectrum up to a cut-off of 2f with
    # independent uniform phases, centred and scaled so that its largest excursion is a.
    T = t.shape[0]
    dt = t[1] - t[0]
    phases = 2 * jnp.pi * v[4 : 4 + T // 2 + 1]
    spectrum = jnp.where(jnp.fft.rfftfreq(T, dt) <= 2.0 * f, jnp.exp(1j * phases), 0.0)
    x = jnp.fft.irfft(spectrum.at[0].set(0.0), n=T)
    return o + a * x / jnp.maximum(jnp.max(jnp.abs(x)), jnp.finfo(t.dtype).tiny)


def _chirp(v, t, r_max):
    a, f, o, _ = _common(v, r_max)
    return chirp(t, a, f, f * _log_uniform(v[4], 0.2, 5.0), o)


def _triangle(v, t, r_max):
    a, f, o, p = _common(v, r_max)
    return triangle(t, a, f, o, p)


def _decaying(v, t, r_max):
    a, f, o, p = _common(v, r_max)
    # Decay time between 5 % and 50 % of the record: large early, below 2 r_max late.
    tau = (t[-1] - t[0] + (t[1] - t[0])) * (0.05 + 0.45 * v[4])
    return o + a * jnp.exp(-(t - t[0]) / tau) * jnp.sin(2 * jnp.pi * f * t + p)


_LEVELS = 12


def _steps(v, t, r_max):
    a, _, o, _ = _common(v, r_max)
    levels = o + a * (2 * v[4 : 4 + _LEVELS] - 1)
    # Random hold times: sorted switching instants over the record. Each switch is a jump within
    # one sample, so the input is not continuous (outside the hypotheses of the paper's Theorem 1).
    span = t[-1] - t[0]
    switches = t[0] + span * jnp.sort(v[4 + _LEVELS : 3 + 2 * _LEVELS])
    return levels[jnp.sum(t[:, None] >= switches, axis=1)]


def _ramp(v, t, r):
    a, f, o, p = _common(v, r[-1])
    # A triangle ten times slower: monotone stretches longer than a window, of range up to 8 r_max.
    return triangle(t, a, f / 10, o, p)


def _touch(v, t, r):
    # A square wave with random holds between −m r_j and +m r_j, m in {1, 2, 4}: products by
    # powers of two are exact, so at m = 1 play j's other envelope is touched exactly and the
    # play does not move; at m = 2, 4 it sweeps.
    j = jnp.minimum((v[0] * r.shape[0]).astype(int), r.shape[0] - 1)
    m = jnp.asarray([1.0, 2.0, 4.0], t.dtype)[jnp.minimum((v[1] * 3).astype(int), 2)]
    # A zero threshold (the play that is u itself) gives way to r_max: the input must move.
    level = m * jnp.where(r[j] > 0, r[j], r[-1])
    span = t[-1] - t[0]
    switches = t[0] + span * jnp.sort(v[2 : 2 + _LEVELS])
    flips = jnp.sum(t[:, None] >= switches, axis=1)
    return jnp.where(flips % 2 == 0, -level, level)


def _nested(v, t, r):
    a, f, o, _ = _common(v, r[-1])
    # One large cycle over the first fifth of the record, then loops of peak-to-peak
    # 2 r_max (1 − ε), ε log-uniform in [1e-9, 1e-2]: just too small to sweep the largest play.
    eps = _log_uniform(v[4], 1e-9, 1e-2)
    span = t[-1] - t[0] + (t[1] - t[0])
    tt = t - t[0]
    first = tt < 0.2 * span
    big = o + a * jnp.sin(2 * jnp.pi * tt / (0.2 * span))
    loops = o + r[-1] * (1 - eps) * jnp.sin(2 * jnp.pi * f * tt)
    return jnp.where(first, big, loops)


def _on_r_max(branch):
    return lambda v, t, r: branch(v, t, r[-1])


_BRANCHES = tuple(
    _on_r_max(b) for b in (_sine, _multisine, _noise, _chirp, _triangle, _decaying, _steps)
) + (_ramp, _touch, _nested)


def _n_uniforms(index: int, T: int) -> int:
    """How many uniforms the generator of family `index` reads for a record of T samples."""
    return (4, 13, 5 + T // 2, 5, 4, 5, 3 + 2 * _LEVELS, 4, 2 + _LEVELS, 5)[index]


def _grid(t):
    t = jnp.asarray(t)
    if t.ndim != 1 or t.shape[0] < 2:
        raise ValueError(f"`t` must be a time grid of at least two samples, got shape {t.shape}")
    return t


def draw_input(key: PRNGKeyArray, family, t: Signal, r_max) -> Signal:
    """One random input of the given family on the time grid `t`.

    **Arguments:**

    - `key`: a PRNG key.
    - `family`: a name from `FAMILIES` or its index (static: it picks the generator).
    - `t`: the uniform time grid (T,), at least two samples.
    - `r_max`: the largest threshold; amplitudes and offsets scale with it. A threshold vector
      (n,) may be given instead (the `touch` family picks one of its thresholds).

    **Returns:** u (T,) in the dtype of `t`.
    """
    (index,) = family_indices((family,))
    t = _grid(t)
    v = jax.random.uniform(key, (_n_uniforms(index, t.shape[0]),), t.dtype)
    r = jnp.atleast_1d(jnp.asarray(r_max, t.dtype))
    return _BRANCHES[index](v, t, r).astype(t.dtype)


def _plays(n) -> int:
    if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 1:
        raise ValueError(f"the number of plays must be a positive whole number, got {n!r}")
    return int(n)


def _thresholds(v, n: int):
    r_max = _log_uniform(v[0], 0.5, 2.0)
    r = jnp.concatenate([jnp.sort(v[1:n]) * r_max, r_max[None]])
    zero_first = (v[n] < 0.5) & (n > 1)
    return r.at[0].set(jnp.where(zero_first, 0.0, r[0]))


def _states(v, r, u0):
    states = u0 + r * (2 * v[1:] - 1)
    return jnp.where(v[0] < 0.5, jnp.zeros_like(r), states)


def draw_thresholds(key: PRNGKeyArray, n: int, *, dtype=float) -> Thresholds:
    """A random increasing threshold set (n,).

    r_max is log-uniform on [0.5, 2]; the others are uniform on (0, r_max), sorted; with
    probability 1/2 the first threshold is 0 (the play is then the input itself), as in the paper.

    **Arguments:** `key`; `n` >= 1 plays; `dtype` of the result.

    **Returns:** (n,) thresholds, increasing, the last one r_max.
    """
    n = _plays(n)
    return _thresholds(jax.random.uniform(key, (n + 1,), jnp.dtype(dtype)), n)


def draw_initial_states(key: PRNGKeyArray, r: Thresholds, u0) -> States:
    """Random initial play states, all zero with probability 1/2.

    Otherwise each state is uniform on [u0 − r_i, u0 + r_i], the states a play can hold when the
    input is u0 (so the first sample does not move it).

    **Arguments:** `key`; thresholds `r` (n,); `u0`, the input's first sample.

    **Returns:** (n,) initial states.
    """
    return _states(jax.random.uniform(key, (r.shape[0] + 1,), r.dtype), r, u0)


def draw_weights(key: PRNGKeyArray, n: int, *, dtype=float) -> Float[Array, " n"]:
    """Random positive weights (n,), uniform on [0.5, 5] (the paper's are 1, 3 and 5)."""
    return 0.5 + 4.5 * jax.random.uniform(key, (_plays(n),), jnp.dtype(dtype))


def family_indices(families) -> tuple[int, ...]:
    """Family names or indices as a tuple of indices into `FAMILIES`; ValueError for unknown ones."""
    if isinstance(families, str):
        families = (families,)
    out = []
    for f in families:
        if isinstance(f, str) and f in FAMILIES:
            out.append(FAMILIES.index(f))
        elif isinstance(f, int | np.integer) and not isinstance(f, bool) and 0 <= f < len(FAMILIES):
            out.append(int(f))
        else:
            raise ValueError(f"unknown input family {f!r}; choose from {FAMILIES}")
    if not out:
        raise ValueError(f"no input family given; choose from {FAMILIES}")
    return tuple(out)


def draw_case(key: PRNGKeyArray, family, t: Signal, n_plays: int):
    """One complete random case of a family: input, thresholds, initial states and weights.

    All of it comes from one uniform vector drawn from `key`, so a case is a pure function of
    (key, family).

    **Arguments:**

    - `key`: a PRNG key.
    - `family`: a name from `FAMILIES` or its index (static).
    - `t`: the time grid (T,); its dtype is the dtype of every result.
    - `n_plays`: n >= 1.

    **Returns:** `(u, r, x0, w)`: the input (T,), thresholds (n,), initial states (n,) and
    weights (n,).
    """
    (index,) = family_indices((family,))
    t = _grid(t)
    n = _plays(n_plays)
    m = _n_uniforms(index, t.shape[0])
    v = jax.random.uniform(key, (m + 3 * n + 2,), t.dtype)
    r = _thresholds(v[m : m + n + 1], n)
    u = _BRANCHES[index](v[:m], t, r).astype(t.dtype)
    x0 = _states(v[m + n + 1 : m + 2 * n + 2], r, u[0])
    w = 0.5 + 4.5 * v[m + 2 * n + 2 :]
    return u, r, x0, w
