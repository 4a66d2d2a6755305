"""numba's ``njit`` with an on-disk cache where one can be written (the package's compiled loops use it).

numba looks for its cache directory when a ``cache=True`` function is defined, i.e. at import: beside the
source file, else in the user's cache directory (``NUMBA_CACHE_DIR`` overrides both). Where neither is
writable (a root-owned install run by a service user, a read-only container) it raises RuntimeError, and
the package would not import. :func:`cached_njit` then compiles without the cache: the same code, compiled
again in each process (a few seconds at the filter's construction, see filters/local_model.py
``compile_now``).
"""

from __future__ import annotations

from numba import njit


def cached_njit(**options):
    """``njit(cache=True, **options)``; plain ``njit(**options)`` where numba finds no writable cache directory."""

    def wrap(func):
        try:
            return njit(cache=True, **options)(func)
        except RuntimeError:  # numba: "cannot cache function ...: no locator available for file ..."
            return njit(**options)(func)

    return wrap


def interrupt_inside(exc: BaseException) -> KeyboardInterrupt | None:
    """The KeyboardInterrupt (Ctrl-C, or SIGTERM/SIGHUP through online_id/cli/signals.py) behind ``exc``, if any.

    A signal handler that raises while a compiled function's dispatcher runs Python code (numba unpickling its
    constants) surfaces as ``SystemError: ... returned a result with an exception set``, the interrupt in its
    chain of causes: callers that stop cleanly on an interrupt look for it here instead of crashing."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return exc
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return None
