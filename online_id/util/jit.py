"""numba's ``njit`` with an on-disk cache where one can be written (the package's compiled loops use it).

numba looks for its cache directory when a ``cache=True`` function is defined, i.e. at import: beside the
source file, else in the user's cache directory (``NUMBA_CACHE_DIR`` overrides both). Where neither is
writable (a root-owned install run by a service user, a read-only container) it raises RuntimeError, and
the package would not import. :func:`cached_njit` then compiles without the cache: the same code, compiled
again in each process (a few seconds at the filter's construction, see filters/local_model.py
``compile_now``).

Loading from the cache (issue 26: start-up to the first sample). Before each cache look-up numba refreshes
its CPU target: it imports and installs every lowering and typing registry of numba (strings, sets, dicts,
random, jitclass, ...), which only compiling uses, about 0.06 s at the process's first compiled call.
Machine code loaded from the cache needs none of it: only numba's runtime (NRT, which its allocations
call) and the modules its environment names, which numba's rebuild imports itself. The package's cached
functions therefore look in the cache first with the runtime initialised (:func:`_load_first`); on a
miss (no cache yet, a new signature, a stale entry), or if the light load fails in any way, numba's own
load runs as before: refresh, look up again, compile. The code run is the same machine code either way.
Where numba's cache object lacks the parts used (another numba version), numba is left as it is.
"""

from __future__ import annotations

from numba import njit


def _load_first(dispatcher) -> None:
    """Make ``dispatcher``'s cache load a cached overload before numba's target refresh (module docstring)."""
    cache = getattr(dispatcher, "_cache", None)
    load, full = getattr(cache, "_load_overload", None), getattr(cache, "load_overload", None)
    try:
        from numba.core.runtime import rtsys
    except ImportError:  # pragma: no cover - another numba: its own load only
        return
    if load is None or full is None or not hasattr(rtsys, "initialize"):  # pragma: no cover - idem
        return

    def load_overload(sig, target_context):
        try:
            rtsys.initialize(target_context)  # what the loaded code calls (numba's refresh does it first)
            loaded = load(sig, target_context)
        except Exception:  # noqa: BLE001 - anything the light path cannot do: numba's own load decides
            loaded = None
        return loaded if loaded is not None else full(sig, target_context)

    cache.load_overload = load_overload


def cached_njit(**options):
    """``njit(cache=True, **options)``; plain ``njit(**options)`` where numba finds no writable cache directory."""

    def wrap(func):
        try:
            dispatcher = njit(cache=True, **options)(func)
        except RuntimeError:  # numba: "cannot cache function ...: no locator available for file ..."
            return njit(**options)(func)
        _load_first(dispatcher)
        return dispatcher

    return wrap
