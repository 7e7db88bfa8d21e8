"""Parameter tables: each value rounded to its standard error, every note where it applies."""

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from piest_jax._parameter_table import HEADER, rounded, row


@pytest.mark.parametrize(
    "value, se, text",
    [
        (0.0913678, 1.006, ("0.1", "± 1.0")),
        (-92.3293, 6.248, ("-92.3", "± 6.2")),
        (0.341305, 0.01081, ("0.341", "± 0.011")),
        (123456.7, 2345.0, ("123500", "± 2300")),
        (5.0, 0.0, ("5", "± 0")),
        (1.0, math.inf, ("1", "undetermined (rank)")),
        (0.05, None, ("0.05", "undetermined (rank)")),
        (92.33, 1e-14, ("92.33", "± 1e-14")),
    ],
)
def test_values_are_rounded_to_their_standard_error(value, se, text):
    assert rounded(value, se) == text


@given(st.floats(-1e6, 1e6), st.floats(1e-8, 1e5))
def test_the_rounding_keeps_two_digits_of_the_error_and_moves_the_value_less_than_it(value, se):
    v, s = rounded(value, se)
    shown = float(s.removeprefix("± "))
    assert abs(shown - se) <= 0.05 * se + 1e-12 * abs(se)  # two significant digits
    assert abs(float(v) - value) <= 0.05 * se * 1.0001 + 1e-9 * abs(value)


def test_rows_say_what_is_not_known():
    assert HEADER.splitlines()[0] == "| parameter | value | std error | note |"
    assert row("w", 0.0913678, 1.006) == "| w | 0.1 | ± 1.0 | within 2 std errors of 0 |"
    assert row("w", 3.0, 1.0) == "| w | 3.0 | ± 1.0 |  |"
    assert row("r", 0.5, math.inf, undetermined=True).endswith("| undetermined (rank) | undetermined |")
    assert row("tau", 0.05, 0.0, held=True) == "| tau | 0.05 | ± 0 | on its bound |"
