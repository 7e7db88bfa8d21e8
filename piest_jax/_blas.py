"""One BLAS thread for host-side work made of many small least-squares problems.

The diagnosis's variable-projection search solves tens of thousands of least-squares problems on
matrices of a few hundred rows by a few dozen columns (`_diagnosis/model.py`). OpenBLAS splits
the larger products over its threads, whose hand-offs then cost more than the arithmetic: a
1200-sample search takes 2.9 s on one thread and 3.6 s on OpenBLAS's default two on a quiet
2-core machine, 3.0 s and 8.0 s with the other core busy (docs/performance.md). The limit holds
only inside the `with` block and is restored after it; it is process-wide meanwhile, as every
BLAS thread setting is.
"""

import contextlib
from collections.abc import Callable
from functools import wraps
from typing import ParamSpec, TypeVar

from threadpoolctl import threadpool_limits

_P = ParamSpec("_P")
_R = TypeVar("_R")


def one_blas_thread() -> contextlib.AbstractContextManager:
    """A context in which NumPy's and SciPy's BLAS run on the calling thread only.

    **Returns:** a context manager; the previous thread counts come back on exit.
    """
    return threadpool_limits(limits=1, user_api="blas")


def on_one_blas_thread(f: Callable[_P, _R]) -> Callable[_P, _R]:
    """`f` run inside `one_blas_thread()`."""

    @wraps(f)
    def wrapped(*args: _P.args, **kwargs: _P.kwargs) -> _R:
        with one_blas_thread():
            return f(*args, **kwargs)

    return wrapped
