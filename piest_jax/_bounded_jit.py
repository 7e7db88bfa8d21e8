"""A compiled function that keeps only its few most recently used programs.

`jax.jit` and `eqx.filter_jit` keep every program they compile for as long as the process runs.
For most functions that is right, but a long-record fit compiles a large program (60-100 MB
resident on a CPU, measured on 2^18 samples) for every play count, lag count and record length
it meets: a model-structure search that fits seven candidates on one stretch of the record and
then the chosen one on all of it held half a gigabyte of programs it would never run again.
`BoundedJit` compiles as `eqx.filter_jit` does (arrays traced, everything else static) but holds
each argument structure's program in a small least-recently-used table; a program pushed out is
released with the `jax.jit` object that held it, and compiled again if its structure returns.
"""

import collections
import functools
from collections.abc import Callable

import equinox as eqx
import jax
import numpy as np


def _signature(args) -> tuple:
    """What selects a program: the arrays' tree, shapes and dtypes, and every static value."""
    dynamic, static = eqx.partition(args, eqx.is_array)
    leaves, tree = jax.tree.flatten(dynamic)
    shapes = tuple((np.shape(a), a.dtype, bool(getattr(a, "weak_type", False))) for a in leaves)
    static_leaves, static_tree = jax.tree.flatten(static)
    return (tree, shapes, static_tree, tuple(static_leaves)), dynamic, static


class BoundedJit:
    """`fn` compiled once per argument structure, at most `size` programs kept.

    **Arguments:** `fn`, the function (positional arguments: arrays are traced, any other leaf
    is static and must be hashable); `size`, the programs kept.
    """

    def __init__(self, fn: Callable, size: int):
        if size < 1:
            raise ValueError(f"`size` must be at least 1, got {size}")
        self._fn = fn
        self._size = size
        self._programs: collections.OrderedDict = collections.OrderedDict()

    def __call__(self, *args):
        key, dynamic, static = _signature(args)
        program = self._programs.pop(key, None)
        if program is None:
            fn = self._fn

            def run(dynamic):
                return fn(*eqx.combine(dynamic, static))

            run.__name__ = fn.__name__
            program = jax.jit(run)
        self._programs[key] = program
        while len(self._programs) > self._size:
            self._programs.popitem(last=False)
        return program(dynamic)

    @property
    def kept(self) -> int:
        """How many compiled programs are held now."""
        return len(self._programs)


def bounded_jit(size: int):
    """A decorator: `fn` as a [`BoundedJit`][piest_jax._bounded_jit.BoundedJit] keeping `size`
    programs, with `fn`'s name and docstring."""

    def wrap(fn: Callable) -> BoundedJit:
        compiled = BoundedJit(fn, size)
        functools.update_wrapper(compiled, fn)
        return compiled

    return wrap
