"""A compiled function that keeps only its latest programs (`_bounded_jit.py`), and host arrays
moved to the device without a compilation (`_checks.to_device`)."""

import gc
import weakref

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from compile_count import Compiles

from piest_jax import _checks
from piest_jax._bounded_jit import BoundedJit, bounded_jit


def _poly(x, a, power):
    # `power` is a Python int: static, so each value is its own program.
    return jnp.sum(a * x**power)


def test_values_match_jit_and_statics_select_programs():
    f = BoundedJit(_poly, 4)
    x = jnp.linspace(0.0, 1.0, 5)
    for power in (1, 2, 3):
        assert float(f(x, 2.0, power)) == pytest.approx(float(jax.jit(_poly, static_argnums=2)(x, 2.0, power)))
    assert f.kept == 3


def test_a_repeated_structure_compiles_nothing():
    f = BoundedJit(_poly, 2)
    x, x2 = jnp.ones(7), jnp.full(7, 2.0, jnp.ones(7).dtype)
    f(x, 1.0, 2)
    with Compiles() as c:
        assert float(f(x2, 1.0, 2)) == 28.0  # other values, the same structure
    assert c.count == 0
    with Compiles() as c:
        f(x2, 3.0, 2)  # a Python number is static: another program
    assert c.count == 1


def test_the_oldest_program_goes_and_is_compiled_again():
    f = BoundedJit(_poly, 2)
    xs = [jnp.ones(n) for n in (3, 4, 5)]
    for x in xs:
        f(x, 1.0, 1)
    assert f.kept == 2
    with Compiles() as c:
        f(xs[2], 1.0, 1)  # kept
        f(xs[1], 1.0, 1)  # kept
    assert c.count == 0
    with Compiles() as c:
        assert float(f(xs[0], 1.0, 1)) == 3.0  # pushed out by the third shape
    assert c.count == 1
    assert f.kept == 2


def test_a_pushed_out_program_is_released():
    f = BoundedJit(_poly, 1)
    f(jnp.ones(3), 1.0, 1)
    program = weakref.ref(next(iter(f._programs.values())))
    f(jnp.ones(4), 1.0, 1)
    gc.collect()
    assert program() is None


def test_the_decorator_keeps_the_name_and_docstring():
    @bounded_jit(1)
    def scaled(x, a):
        """x times a."""
        return x * a

    assert isinstance(scaled, BoundedJit)
    assert (scaled.__name__, scaled.__doc__) == ("scaled", "x times a.")
    np.testing.assert_array_equal(np.asarray(scaled(jnp.arange(3.0), 2.0)), [0.0, 2.0, 4.0])


def test_size_must_be_positive():
    with pytest.raises(ValueError, match="size"):
        BoundedJit(_poly, 0)


def test_to_device_copies_and_compiles_nothing():
    a = np.arange(11.0)
    # Whatever earlier tests in this process left running or unreferenced settles first, so that
    # only the copy is counted (`jnp.asarray` here would compile one program).
    jax.effects_barrier()
    gc.collect()
    with Compiles() as c:
        b = _checks.to_device(a)
    assert c.count == 0
    a[0] = 99.0
    assert float(b[0]) == 0.0
    assert b.dtype == jnp.result_type(float)


def test_as_float_array_from_numpy_keeps_values_and_kind():
    ints = np.array([1, 2, 3])
    out = _checks.as_float_array(ints, "x")
    assert jnp.issubdtype(out.dtype, jnp.floating)
    np.testing.assert_array_equal(np.asarray(out), [1.0, 2.0, 3.0])
    f32 = np.linspace(0, 1, 4, dtype=np.float32)
    assert _checks.as_float_array(f32, "x").dtype == jnp.float32
