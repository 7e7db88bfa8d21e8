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


class _NoBar:
    n = 0

    def update(self, n=1):
        self.n += n

    def close(self):
        pass


def bar(total: int, *, desc=None, quiet: bool = False):
    """A progress bar advanced by hand (`.update(n)`, `.n`, `.close()`), shown only when stderr
    is a terminal (and tqdm is installed); tqdm's estimate of the time left goes with it.

    **Arguments:** `total`, the count at which the bar is full; `desc`, a label; `quiet`, never
    show a bar.

    **Returns:** the bar.
    """
    show = not quiet and sys.stderr.isatty()
    if tqdm is None:
        return _NoBar()
    return tqdm(total=total, desc=desc, disable=not show, leave=False, file=sys.stderr)
