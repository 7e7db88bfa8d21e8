"""Column names and cells as users' files have them: names with units, names chosen by the user,
quoted fields, and what is not a number.

- A header cell is matched by its name without quotes, case or a trailing unit in brackets or
  parentheses: `t [s]`, `"T (s)"` and `t` all name the column `t`. A header without t, u, y
  whose columns' leading words name the roles (`ROLE_WORDS`: time; input or voltage; output or
  displacement), one column each, is read as t, u, y: `Time [s],Voltage [V],Displacement [um]`.
- `columns=("time_s", "voltage_V", "displacement_um")` names the file's columns that hold t, u
  and y (matched the same way); the CLI's `--columns TIME,INPUT,OUTPUT` passes it. Two names
  (`columns=("H", "B")`) name the input and output of data without a time column.
- Data without time (quasi-static sweeps, B-H loops) count samples instead: a record whose time
  column is absent, or is named as a sample index (`INDEX_NAMES`), has `time_is_index` set.
- A column named `segment` labels the segments of a record made of several runs (loops,
  reversal curves); the rows of one segment are contiguous.
- A cell is a number when it is an ASCII decimal or exponent literal, optionally in quotes (as
  spreadsheet exports write every field); `1_000` (Python's digit grouping) and digits of other
  scripts (`١٢`) are not, although Python's `float` reads both.
"""

import re

# The leading words that name a column's role when a header does not say t, u, y:
# `Time [s],Voltage [V],Displacement [um]` is a record.
ROLE_WORDS = {"t": ("time",), "u": ("input", "voltage"), "y": ("output", "displacement")}

# Names of a time column that counts samples rather than seconds.
INDEX_NAMES = ("index", "idx", "sample", "n", "k", "i")
SEGMENT = "segment"

_UNIT = re.compile(r"\s*(\[[^\[\]]*\]|\([^()]*\))\s*$")
_NUMBER = re.compile(r"[+-]?((\d+\.?\d*|\.\d+)([eE][+-]?\d+)?|inf(inity)?|nan)", re.IGNORECASE | re.ASCII)


def unquote(cell: str) -> str:
    """A cell without surrounding blanks and one pair of surrounding quotes."""
    cell = cell.strip()
    if len(cell) >= 2 and cell[0] == cell[-1] and cell[0] in "\"'":
        cell = cell[1:-1].strip()
    return cell


def base_name(cell: str) -> str:
    """A header cell's name: unquoted, lower case, a trailing `[unit]` or `(unit)` removed."""
    name = unquote(cell).lower()
    stripped = _UNIT.sub("", name)
    return stripped if stripped else name


def to_number(cell: str) -> float | None:
    """The cell's value, or None when it is not a number (see the module's text)."""
    text = unquote(cell)
    if not _NUMBER.fullmatch(text):
        return None
    return float(text)


def column_names(columns, source: str) -> tuple[str | None, str, str] | None:
    """The base names `columns` gives for t, u and y (None: the file's own).

    **Arguments:** `columns`, None, a sequence of three names (time, input, output) or of two
    (input, output: data without time), or one string `"A,B,C"` / `"A,B"`; `source`, for the
    message.

    **Returns:** the base names, the time's None when two are given. Raises `ValueError` for
    anything but two or three distinct names.
    """
    if columns is None:
        return None
    if isinstance(columns, str):
        columns = columns.split(",")
    names = tuple(base_name(str(c)) for c in columns)
    if len(names) not in (2, 3) or not all(names) or len(set(names)) != len(names):
        raise ValueError(
            f"{source}: columns= needs three distinct names, for time, input and output "
            f"(e.g. time_s,voltage_V,displacement_um), or two for data without time (e.g. H,B); "
            f"got {list(columns)!r}"
        )
    if len(names) == 3:
        return names[0], names[1], names[2]
    return None, names[0], names[1]


def leading_word(name: str) -> str:
    """A base name's first word: `displacement_um` and `displacement um` give `displacement`."""
    return re.split(r"[^0-9a-z]+", name, maxsplit=1)[0]


def by_role(names) -> tuple[str, str, str] | None:
    """The (time, input, output) columns of base `names` by their leading words (`ROLE_WORDS`),
    when each role has exactly one; None otherwise."""
    chosen = []
    for role in ("t", "u", "y"):
        hits = [n for n in names if leading_word(n) in ROLE_WORDS[role]]
        if len(hits) != 1:
            return None
        chosen.append(hits[0])
    return chosen[0], chosen[1], chosen[2]
