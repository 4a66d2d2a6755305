"""One BLAS thread for online-id's work.

Every matrix here is small (6×6 to 17×17, or a few thousand rows by six): a multi-threaded BLAS
spends far more on waking its threads than on the arithmetic. Measured on this project's 2-core
machines, one diagnosis of a 15 s run took 12.7 s with OpenBLAS's default threads and 2.8 s with
one. The limit is applied for the duration of a call (the CLI, a fit, a diagnosis, an estimation
run) and restored afterwards, so a program that imports online-id keeps its own setting elsewhere.
"""

from __future__ import annotations

import functools

from threadpoolctl import threadpool_limits


def single_blas_thread(func):
    """Decorator: run ``func`` with BLAS limited to one thread."""

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        with threadpool_limits(limits=1, user_api="blas"):
            return func(*args, **kwargs)

    return wrapper
