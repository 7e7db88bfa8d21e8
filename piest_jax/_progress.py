"""Progress bars that show on a terminal and stay quiet elsewhere."""

import sys

try:
    # The plain bar: it only ever draws on a terminal, and the notebook variant would need
    # ipywidgets.
    from tqdm import tqdm
except ImportError:  # tqdm comes with the `cli` extra; without it there are no bars
    tqdm = None


def progress(iterable, *, total=None, desc=None, quiet: bool = False):
    """Wrap `iterable` in a progress bar on stderr, shown only when stderr is a terminal (and
    tqdm is installed).

    **Arguments:** `iterable`; `total`, its length if it has none; `desc`, a label; `quiet`,
    never show a bar.

    **Returns:** an iterable yielding the same items.
    """
    show = not quiet and sys.stderr.isatty()
    if tqdm is None:
        return iterable
    return tqdm(iterable, total=total, desc=desc, disable=not show, leave=False, file=sys.stderr)
