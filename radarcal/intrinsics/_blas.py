"""Single-threaded BLAS for the small dense problems of the intrinsics solvers.

The normal matrices here are a few hundred wide: multi-threaded OpenBLAS buys nothing and, on a loaded machine,
costs up to 10x (measured: stereo solve 0.45 s single-threaded vs 1.5-5.4 s with the default threads while other
processes use the cores). Uses threadpoolctl when installed; a no-op otherwise.
"""

from __future__ import annotations

import functools
from contextlib import nullcontext

__all__ = ["single_thread_blas"]


def _limits():
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # optional: only a speed matter
        return nullcontext()
    return threadpool_limits(1, user_api="blas")


def single_thread_blas(fn):
    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        with _limits():
            return fn(*args, **kwargs)

    return wrapper
