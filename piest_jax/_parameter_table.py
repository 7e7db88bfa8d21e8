"""Parameters as a Markdown `value ± std error` table, each value rounded to its standard error."""

import math

HEADER = "| parameter | value | std error | note |\n|---|---|---|---|"
# Decimals shown at most: a standard error of 1e-12 on a value of 92 does not need 14 digits.
MAX_DECIMALS = 10


def rounded(value: float, std_error: float | None) -> tuple[str, str]:
    """`value` to the second significant digit of `std_error`, and the standard error so:
    (0.0913678, 1.006) gives ("0.1", "± 1.0"). An unknown or infinite one gives the value to six
    digits and "undetermined (rank)", a zero one (a parameter held on a bound) "± 0", one below
    `MAX_DECIMALS` decimals the value to six digits and the error to two."""
    if std_error is None or not math.isfinite(std_error):
        return f"{value:.6g}", "undetermined (rank)"
    if std_error == 0:
        return f"{value:.6g}", "± 0"
    decimals = 1 - math.floor(math.log10(std_error))
    if decimals > MAX_DECIMALS:
        return f"{value:.6g}", f"± {std_error:.2g}"
    if decimals > 0:
        return f"{value:.{decimals}f}", f"± {std_error:.{decimals}f}"
    scale = 10.0 ** (-decimals)
    return f"{round(value / scale) * scale:.0f}", f"± {round(std_error / scale) * scale:.0f}"


def row(name: str, value: float, std_error: float | None, *, undetermined=False, held=False) -> str:
    """One table row; the note says `undetermined`, `on its bound`, or `within 2 std errors of 0`
    (a value the record does not tell from zero)."""
    v, se = rounded(value, std_error)
    if undetermined:
        note = "undetermined"
    elif held:
        note = "on its bound"
    elif std_error is not None and math.isfinite(std_error) and abs(value) < 2 * std_error:
        note = "within 2 std errors of 0"
    else:
        note = ""
    return f"| {name} | {v} | {se} | {note} |"
