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

