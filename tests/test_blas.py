"""The diagnosis runs its small least-squares solves on one BLAS thread, and restores the count."""

import numpy as np
from threadpoolctl import threadpool_info, threadpool_limits

import piest_jax as pj
from piest_jax._blas import on_one_blas_thread, one_blas_thread


def _blas_threads():
    return sorted(i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas")


def test_one_thread_inside_and_the_count_restored_after():
    np.ones((4, 4)) @ np.ones((4, 4))  # NumPy's BLAS is loaded
    with threadpool_limits(limits=2, user_api="blas"):
        before = _blas_threads()
        assert before and all(n == 2 for n in before)
        with one_blas_thread():
            assert all(n == 1 for n in _blas_threads())
        assert _blas_threads() == before


def test_the_search_runs_on_one_thread(monkeypatch):
    from piest_jax._diagnosis import diagnose as _diagnose

    seen = []
    # The search's first step after its checks is the scaling: record the thread count there.
    real = _diagnose.scaling_of

    def spy(*args, **kwargs):
        seen.append(_blas_threads())
        return real(*args, **kwargs)

    monkeypatch.setattr(_diagnose, "scaling_of", spy)
    t = np.arange(400) * 0.01
    u = np.sin(2 * np.pi * t)
    rec = pj.Record(t, u, u + 0.01 * np.cos(7 * t))
    with threadpool_limits(limits=2, user_api="blas"):
        _diagnose.search(rec, candidates=(), solver=None, uncertainty=False)
        after = _blas_threads()
    assert seen and all(n == 1 for n in seen[0])
    assert all(n == 2 for n in after)


def test_the_wrapper_keeps_the_name_and_result():
    @on_one_blas_thread
    def f(x, *, k=1):
        """doc"""
        return _blas_threads(), x + k

    threads, value = f(1, k=2)
    assert value == 3 and f.__name__ == "f" and f.__doc__ == "doc"
    assert all(n == 1 for n in threads)
