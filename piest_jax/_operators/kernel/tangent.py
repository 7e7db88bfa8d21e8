"""Forward-mode derivatives of the kernel: the play bank's tangent as a linear JAX primitive.

Along a direction (du, dr, dx0) the tangent of a play is piecewise a copy: where a bound moved the
state at step t, dx_t = du_t ∓ dr (−dr on the lower bound x = u − r, +dr on the upper one x = u + r);
where it held, dx_t = dx_{t−1}; before the first move, dx0. The kernel's forward pass records which
steps moved (its branch codes) and a tangent kernel runs this recurrence over them, so the tangent
shares the kernel's convention at ties (a tie holds).

The tangent is linear in (du, dr, dx0) and its transpose is the kernel's backward pass. Written as
a primitive with that transpose rule, reverse mode keeps the backward kernel (JAX transposes the
tangent instead of differentiating the forward pass), and forward mode (`jvp`, `jacfwd`,
`linearize`, forward-mode solvers) gets the tangent kernel. A batching rule makes it compose with
`vmap` in either order with both modes.
"""

from collections.abc import Callable, Sequence

import jax
import jax.numpy as jnp
from jax.extend.core import Primitive
from jax.interpreters import ad, batching, mlir
from jaxtyping import Array


def _over_leading(fn: Callable, n_leading: int) -> Callable:
    for _ in range(n_leading):
        fn = jax.vmap(fn)
    return fn


def linear_primitive(
    name: str,
    n_constants: int,
    tangent: Callable[..., Array],
    out_shape: Callable[..., tuple[int, ...]],
    transpose: Callable[..., Sequence[Array]],
) -> Primitive:
    """A primitive `p(*constants, *tangents)`, linear in its tangents, with a given transpose.

    **Arguments:**

    - `name`: the primitive's name (seen in jaxprs).
    - `n_constants`: how many leading operands are constants (the forward pass's values).
    - `tangent`: the unbatched rule, `tangent(*constants, *tangents) -> Array`.
    - `out_shape`: the unbatched output shape from the unbatched operand shapes.
    - `transpose`: the unbatched transpose, `transpose(*constants, cotangent) -> cotangents of the
      tangents`, in their order.

    **Returns:** the primitive. Operands may carry the same leading batch axes (the batching rule
    moves every batch axis to the front, broadcasting unbatched operands); the signal `u` is the
    first constant and has one unbatched axis, which tells how many leading axes there are.
    """
    p = Primitive(name)

    def leading(constants) -> int:
        return constants[0].ndim - 1

    def impl(*args):
        return _over_leading(tangent, leading(args))(*args)

    def abstract(*args):
        n = leading(args)
        shape = out_shape(*(a.shape[n:] for a in args))
        return jax.core.ShapedArray(args[0].shape[:n] + shape, args[0].dtype)

    def batch(args, dims):
        size = next(a.shape[d] for a, d in zip(args, dims) if d is not None)
        front = [
            jnp.broadcast_to(a, (size,) + a.shape) if d is None else jnp.moveaxis(a, d, 0) for a, d in zip(args, dims)
        ]
        return p.bind(*front), 0

    def transpose_rule(ct, *args):
        constants, tangents = args[:n_constants], args[n_constants:]
        if any(ad.is_undefined_primal(a) for a in constants):
            raise ValueError(f"{name} is linear in its tangents only")
        if type(ct) is ad.Zero:
            return [None] * n_constants + [ad.Zero(a.aval) if ad.is_undefined_primal(a) else None for a in tangents]
        cts = _over_leading(transpose, leading(constants))(*constants, ct)
        return [None] * n_constants + [g if ad.is_undefined_primal(a) else None for g, a in zip(cts, tangents)]

    p.def_impl(jax.jit(impl))
    p.def_abstract_eval(abstract)
    mlir.register_lowering(p, mlir.lower_fun(impl, multiple_results=False))
    batching.primitive_batchers[p] = batch
    ad.primitive_transposes[p] = transpose_rule
    return p
