"""Progress bars that show on a terminal and stay quiet elsewhere."""

import sys

# The plain bar: it only ever draws on a terminal, and the notebook variant would need ipywidgets.
from tqdm import tqdm


def progress(iterable, *, total=None, desc=None, quiet: bool = False):
    """Wrap `iterable` in a progress bar on stderr, shown only when stderr is a terminal.

    **Arguments:** `iterable`; `total`, its length if it has none; `desc`, a label; `quiet`,
    never show a bar.

    **Returns:** an iterable yielding the same items.
    """
    show = not quiet and sys.stderr.isatty()
    return tqdm(iterable, total=total, desc=desc, disable=not show, leave=False, file=sys.stderr)
