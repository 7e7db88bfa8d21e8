"""Random draws for Monte Carlo studies of excitation: inputs, thresholds, initial states, weights.

Every draw comes from an explicit PRNG key and is unbatched: one key and a family give one input
(T,), one threshold vector (n,), one initial-state vector (n,), one weight vector (n,). Batch with
`jax.vmap` over keys; the family is static (it picks the generator), so a batch mixing families
runs one vmap per family instead of evaluating every generator for every draw.
"""

import functools

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, PRNGKeyArray

from .. import _checks
from .._custom_types import Signal, States, Thresholds
from .families import FAMILIES, FAMILY, family_indices
from .family import log_uniform


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
    return _input(_checks.prng_key(key), index, _grid(t), r_max)


# The draws are compiled as one program each (under an outer `jit`, a call nested in its program):
# run op by op, every new grid length compiled each of their dozen operations.
@functools.partial(jax.jit, static_argnums=1)
def _input(key, index: int, t, r_max):
    fam = FAMILY[FAMILIES[index]]
    v = jax.random.uniform(key, (fam.n_uniforms(t.shape[0]),), t.dtype)
    r = jnp.atleast_1d(jnp.asarray(r_max, t.dtype))
    return fam.input(v, t, r).astype(t.dtype)


def _plays(n) -> int:
    if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 1:
        raise ValueError(f"the number of plays must be a positive whole number, got {n!r}")
    return int(n)


def _thresholds(v, n: int):
    r_max = log_uniform(v[0], 0.5, 2.0)
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
    return _thresholds(jax.random.uniform(_checks.prng_key(key), (n + 1,), jnp.dtype(dtype)), n)


def draw_initial_states(key: PRNGKeyArray, r: Thresholds, u0) -> States:
    """Random initial play states, all zero with probability 1/2.

    Otherwise each state is uniform on [u0 − r_i, u0 + r_i], the states a play can hold when the
    input is u0 (so the first sample does not move it).

    **Arguments:** `key`; thresholds `r` (n,); `u0`, the input's first sample.

    **Returns:** (n,) initial states.
    """
    return _states(jax.random.uniform(_checks.prng_key(key), (r.shape[0] + 1,), r.dtype), r, u0)


def draw_weights(key: PRNGKeyArray, n: int, *, dtype=float) -> Float[Array, " n"]:
    """Random positive weights (n,), uniform on [0.5, 5] (the paper's are 1, 3 and 5)."""
    return 0.5 + 4.5 * jax.random.uniform(_checks.prng_key(key), (_plays(n),), jnp.dtype(dtype))


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
    return _case(_checks.prng_key(key), index, _grid(t), _plays(n_plays))


@functools.partial(jax.jit, static_argnums=(1, 3))
def _case(key, index: int, t, n: int):
    fam = FAMILY[FAMILIES[index]]
    m = fam.n_uniforms(t.shape[0])
    v = jax.random.uniform(key, (m + 3 * n + 2,), t.dtype)
    r = _thresholds(v[m : m + n + 1], n)
    u = fam.input(v[:m], t, r).astype(t.dtype)
    x0 = _states(v[m + n + 1 : m + 2 * n + 2], r, u[0])
    w = 0.5 + 4.5 * v[m + 2 * n + 2 :]
    return u, r, x0, w
