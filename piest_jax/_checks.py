"""Validation helpers shared by the public entry points.

Static problems (shapes, configuration) raise `ValueError` at trace time. Problems that can only be
seen in traced values go through `eqx.error_if`, so they surface inside `jit` as well.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array


def is_concrete(x) -> bool:
    """True when `x` holds values we can inspect now (not a tracer)."""
    return not isinstance(x, jax.core.Tracer)


def is_whole(v) -> bool:
    """True for a Python or NumPy integer (not a bool): what a count or a length may be."""
    return isinstance(v, int | np.integer) and not isinstance(v, bool | np.bool_)


def prng_key(key, name: str = "key"):
    """A new-style PRNG key from either kind JAX users hold: `jax.random.key(0)` (returned as it
    is) or the legacy `jax.random.PRNGKey(0)` (uint32 (2,), wrapped with the default
    implementation, so both give the same numbers)."""
    if isinstance(key, jax.Array) and jax.dtypes.issubdtype(key.dtype, jax.dtypes.prng_key):
        if key.shape != ():
            raise ValueError(f"`{name}` must be one PRNG key, got an array of keys of shape {key.shape}")
        return key
    arr = np.asarray(key) if is_concrete(key) else key
    if getattr(arr, "dtype", None) == np.uint32 and getattr(arr, "shape", None) == (2,):
        # Any uint32 array-like is wrapped (NumPy's too); the annotation names jax.Array only.
        return jax.random.wrap_key_data(arr)  # type: ignore[arg-type]
    raise ValueError(
        f"`{name}` must be a PRNG key such as jax.random.key(0) or jax.random.PRNGKey(0), got "
        f"{type(key).__name__} {getattr(key, 'dtype', '')}{list(getattr(key, 'shape', ()))}"
    )


def to_device(x) -> Array:
    """A NumPy array as a JAX array of the same values (float64 becomes float32 where JAX runs
    without 64-bit types, as `jnp.asarray` does), not sharing the caller's memory.

    Not `jnp.asarray`: from jax 0.8 on it compiles a small program for every shape and dtype it
    is given, a compilation (and about a megabyte kept) per record length and play count. The
    host copy comes first because `jax.device_put` may alias a CPU array's memory, even when
    told not to (seen with `may_alias=False`): the copy it may alias is then its own.
    """
    return jax.device_put(np.array(x, copy=True))


def as_float_array(x, name: str) -> Array:
    """Convert to a floating JAX array, keeping float64 when it is enabled and given."""
    if isinstance(x, np.ndarray):
        if not np.issubdtype(x.dtype, np.floating):
            x = x.astype(np.float64)
        return to_device(x)
    arr = jnp.asarray(x)
    if not jnp.issubdtype(arr.dtype, jnp.floating):
        arr = arr.astype(jnp.result_type(float))
    return arr


def signal(u, name: str = "u") -> Array:
    """A one-dimensional sampled signal with at least one sample."""
    u = as_float_array(u, name)
    if u.ndim != 1:
        raise ValueError(
            f"`{name}` must be one signal of shape (T,), got shape {u.shape}; batch several signals with jax.vmap"
        )
    if u.shape[0] < 1:
        raise ValueError(f"`{name}` is empty: it needs at least one sample")
    return u


def finite(x: Array, name: str) -> Array:
    """Reject NaN or inf, statically when possible, else through `eqx.error_if`."""
    if is_concrete(x):
        if not bool(np.all(np.isfinite(np.asarray(x)))):
            raise ValueError(f"`{name}` contains NaN or inf")
        return x
    return eqx.error_if(x, ~jnp.all(jnp.isfinite(x)), f"`{name}` contains NaN or inf")


def thresholds(r, name: str = "thresholds", *, sorted_: bool = False) -> Array:
    """Thresholds: a scalar or a vector, finite and non-negative (and increasing if asked)."""
    r = as_float_array(r, name)
    if r.ndim > 1:
        raise ValueError(f"`{name}` must be a scalar or a vector (n,), got shape {r.shape}")
    if r.ndim == 1 and r.shape[0] < 1:
        raise ValueError(f"`{name}` is empty: a PI operator needs at least one play")
    if is_concrete(r):
        rn = np.asarray(r)
        if not np.all(np.isfinite(rn)):
            raise ValueError(f"`{name}` contains NaN or inf")
        if np.any(rn < 0):
            raise ValueError(f"`{name}` must be non-negative, got min {rn.min():.6g}")
        if sorted_ and rn.ndim == 1 and np.any(np.diff(rn) <= 0):
            raise ValueError(f"`{name}` must be strictly increasing (0 = r_1 < r_2 < ... < r_n)")
        return r
    bad = ~jnp.all(jnp.isfinite(r)) | jnp.any(r < 0)
    r = eqx.error_if(r, bad, f"`{name}` must be finite and non-negative")
    if sorted_ and r.ndim == 1 and r.shape[0] > 1:
        r = eqx.error_if(r, jnp.any(jnp.diff(r) <= 0), f"`{name}` must be strictly increasing")
    return r


def per_play(x, n: int | None, name: str) -> Array:
    """A per-play quantity given as a scalar or as a vector of length n."""
    x = as_float_array(x, name)
    if x.ndim > 1:
        raise ValueError(f"`{name}` must be a scalar or a vector, got shape {x.shape}")
    if x.ndim == 1:
        if n is None:
            raise ValueError(f"`{name}` is a vector {x.shape} but the threshold is a scalar")
        if x.shape[0] != n:
            raise ValueError(f"`{name}` has {x.shape[0]} entries but there are {n} thresholds")
    return x
