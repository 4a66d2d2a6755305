"""One BLAS thread for online-id's work.

Every matrix here is small (6×6 to 17×17, or a few thousand rows by six): a multi-threaded BLAS
spends far more on waking its threads than on the arithmetic. Measured on this project's 2-core
machines, one diagnosis of a 15 s run took 12.7 s with OpenBLAS's default threads and 2.8 s with
one. The limit is applied for the duration of a call (the CLI, a fit, a diagnosis, an estimation
run) and restored afterwards, so a program that imports online-id keeps its own setting elsewhere.
"""

from __future__ import annotations

import functools
import os

from threadpoolctl import threadpool_limits

from online_id.errors import OnlineIdError


def single_blas_thread(func):
    """Decorator: run ``func`` with BLAS limited to one thread."""

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        with threadpool_limits(limits=1, user_api="blas"):
            return func(*args, **kwargs)

    return wrapper


#: The environment variable that sets how many threads a fit's Jacobian columns take (:func:`fit_threads`).
THREADS_ENV = "ONLINE_ID_FIT_THREADS"


def fit_threads() -> int:
    """Threads for a force-law fit's Jacobian columns, the diagnosis's fits side by side and the pieces of a long run's
    tyre pass: ``ONLINE_ID_FIT_THREADS``, else the cores this process may use (at most 8); 1 runs them one by one."""
    text = os.environ.get(THREADS_ENV, "").strip()
    if text:
        try:
            return max(1, int(text))
        except ValueError:
            raise OnlineIdError(f"{THREADS_ENV}={text!r}: expected a whole number of threads") from None
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # (not on Linux)
        cores = os.cpu_count() or 1
    return max(1, min(cores, 8))
