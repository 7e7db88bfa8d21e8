"""Solving many starts (or folds) in batches: `batch` at a time under `vmap`, the batches one
after another, so that memory grows with batch x T rather than with their number x T."""

import jax
import jax.numpy as jnp
from jax import lax


def map_in_batches(fn, xs, batch: int | None):
    """`jax.vmap(fn)(xs)`, computed `batch` leading entries at a time.

    `lax.map(fn, xs, batch_size=batch)` does the same, but it flattens its outputs with a
    reshape to `-1`, which fails for an output with a zero-size axis (a one-play fit's empty
    threshold increments); the batches are formed here with explicit shapes instead.

    **Arguments:** `fn`, a function of one entry of `xs`; `xs`, a pytree of arrays sharing their
    leading size n; `batch`, entries per batch (None or >= n: all at once).

    **Returns:** the pytree `jax.vmap(fn)(xs)` would return.
    """
    n = jax.tree.leaves(xs)[0].shape[0]
    if batch is None or batch >= n:
        return jax.vmap(fn)(xs)
    batch = int(batch)
    if batch < 1:
        raise ValueError(f"`batch` must be a positive whole number, got {batch}")
    full = n // batch * batch
    head = jax.tree.map(lambda a: a[:full].reshape((n // batch, batch) + a.shape[1:]), xs)
    ys = jax.tree.map(lambda a: a.reshape((full,) + a.shape[2:]), lax.map(jax.vmap(fn), head))
    if full == n:
        return ys
    tail = jax.vmap(fn)(jax.tree.map(lambda a: a[full:], xs))
    return jax.tree.map(lambda a, b: jnp.concatenate([a, b]), ys, tail)
