"""numba's ``njit`` with an on-disk cache in the user's cache directory (the package's compiled loops use it).

Where the cache goes (issue 40). numba's own ``cache=True`` writes beside the source file, i.e. into the
installed package (``site-packages/online_id/**/__pycache__/*.nbi``, ``*.nbc``). ``pip uninstall`` does not
know those files and leaves them, in a folder ``online_id/`` with no ``__init__.py``; a later ``pip install
-e .`` into the same environment then imports that leftover folder as a namespace package before the
editable checkout: ``ImportError: cannot import name '__version__' from 'online_id' (unknown location)``.
:func:`cached_njit` therefore keeps the cache where a user's caches belong: numba's ``NUMBA_CACHE_DIR`` when
it is set, else ``online-id/numba`` in the user cache directory (``$XDG_CACHE_HOME``, by default
``~/.cache``, on Linux; ``~/Library/Caches`` on macOS; ``%LOCALAPPDATA%`` on Windows). Entries are keyed
as numba keys them (the source file's folder, its content hash, the CPU, numba's and Python's versions):
a reinstall in the same place loads them, an edited file compiles again. numba keys a function's entry by its
own file alone, and a compiled function carries the code of the compiled functions it calls from other modules:
after an edit to such a callee (a ``git pull`` onto an editable install) numba loaded the caller's old machine
code, the callee's old arithmetic in it (seen here: an estimate 1e-14 off a fresh cache's after an edit of
``model/compiled.py`` and its revert). Every entry's stamp therefore also holds a digest of the package's compiled
sources (:func:`sources_digest`, the modules with compiled code): an edit to any of them compiles them all again.
Where no such directory can be
written (a read-only home, a service user without one), the functions compile without the cache: the same
code, compiled again in each process.

Loading from the cache (issue 26: start-up to the first sample). Before each cache look-up numba refreshes
its CPU target: it imports and installs every lowering and typing registry of numba (strings, sets, dicts,
random, jitclass, ...), which only compiling uses, about 0.06 s at the process's first compiled call.
Machine code loaded from the cache needs none of it: only numba's runtime (NRT, which its allocations
call) and the modules its environment names, which numba's rebuild imports itself. The package's cached
functions therefore look in the cache first with the runtime initialised; on a miss (no cache yet, a new
signature, a stale entry), or if the light load fails in any way, numba's own load runs as before:
refresh, look up again, compile. The code run is the same machine code either way.

The first compile of a process (issue 40): :mod:`online_id.util.first_compile` hears of it once (the CLI
prints one line on stderr: a first run after installing waits for numba), and numba's message for a slice
assigned from an array of another shape is made its plain one (:func:`_plain_slice_shape_error`).

Everything here reaches into numba's caching and typing internals; where numba lacks the parts used
(another version), numba's behaviour is left as it is, and the functions compile without a cache.
"""

from __future__ import annotations

import functools
import hashlib
import os
from pathlib import Path

from numba import njit

from online_id.util import first_compile

#: The folder under the user cache directory's ``online-id`` where compiled code is kept.
CACHE_SUBDIR = "numba"


def cache_dir() -> str:
    """Where the package's compiled code is cached: ``NUMBA_CACHE_DIR`` when set (numba's own setting, read
    when numba was imported), else ``<user cache directory>/online-id/numba`` (module docstring)."""
    from numba.core import config

    if config.CACHE_DIR:
        return str(config.CACHE_DIR)
    return os.path.join(_user_cache_dir(), CACHE_SUBDIR)


def _user_cache_dir() -> str:
    """The platform's user cache directory for online-id (``$XDG_CACHE_HOME/online-id`` on Linux)."""
    try:
        from numba.misc.appdirs import AppDirs  # (numba's copy of appdirs: no dependency of our own)
    except ImportError:  # pragma: no cover - another numba
        base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
        return os.path.join(base, "online-id")
    return AppDirs(appname="online-id", appauthor=False).user_cache_dir


def _function_cache_class():
    """numba's ``FunctionCache`` with one locator: :func:`cache_dir` (None where numba lacks the parts)."""
    try:
        from numba.core import caching
    except ImportError:  # pragma: no cover - another numba
        return None
    user_wide = getattr(caching, "UserWideCacheLocator", None) or getattr(caching, "_UserWideCacheLocator", None)
    impl = getattr(caching, "CompileResultCacheImpl", None)
    function_cache = getattr(caching, "FunctionCache", None)
    if user_wide is None or impl is None or function_cache is None:  # pragma: no cover - another numba
        return None

    class UserCacheLocator(user_wide):
        """numba's user-wide locator (exists, writable, keyed by the source's folder) at :func:`cache_dir`."""

        def __init__(self, py_func, py_file):
            self._py_file = py_file
            self._lineno = py_func.__code__.co_firstlineno
            self._cache_path = os.path.join(cache_dir(), self.get_suitable_cache_subpath(py_file))

        def get_source_stamp(self):
            """numba's stamp of the function's own file, and the digest of the package's compiled sources (a
            callee in another module edited: the entry is stale; see the module docstring)."""
            return super().get_source_stamp(), sources_digest()

    class UserCacheImpl(impl):
        _locator_classes = [UserCacheLocator]

    class UserFunctionCache(function_cache):
        _impl_class = UserCacheImpl

    return UserFunctionCache


#: The package's modules with compiled code (``cached_njit``), from the package's folder: what a cached function's
#: stamp also covers (:func:`sources_digest`; tests/test_jit_cache.py checks the list is whole).
COMPILED_MODULES = ("filters/block_close.py", "filters/kinematics.py", "filters/sigma_block.py",
                    "filters/spectral_group.py", "filters/tyre_block.py", "model/compiled.py", "model/tyres.py",
                    "sim/block_loop.py")


@functools.cache
def sources_digest(root: str | None = None) -> str:
    """A digest of the package's compiled sources: the :data:`COMPILED_MODULES` under ``root`` (default: the
    ``online_id`` package), by path and content (about a millisecond, once a process)."""
    base = Path(root) if root is not None else Path(__file__).resolve().parents[1]
    digest = hashlib.sha256()
    for name in COMPILED_MODULES:
        path = base / name
        digest.update(name.encode() + b"\0" + (path.read_bytes() if path.exists() else b""))
    return digest.hexdigest()


_FUNCTION_CACHE = _function_cache_class()


def _watch_loads(dispatcher) -> None:
    """Make ``dispatcher``'s cache load a cached overload before numba's target refresh, and tell
    :func:`_compiling` when nothing was loaded (a compile follows). See the module docstring."""
    cache = getattr(dispatcher, "_cache", None)
    full = getattr(cache, "load_overload", None)
    if full is None:  # pragma: no cover - another numba
        return
    light = getattr(cache, "_load_overload", None)
    try:
        from numba.core.runtime import rtsys
    except ImportError:  # pragma: no cover - another numba: its own load only
        rtsys = None
    if rtsys is None or not hasattr(rtsys, "initialize"):  # pragma: no cover - idem
        light = None

    def load_overload(sig, target_context):
        loaded = None
        if light is not None:
            try:
                rtsys.initialize(target_context)  # what the loaded code calls (numba's refresh does it first)
                loaded = light(sig, target_context)
            except Exception:  # noqa: BLE001 - anything the light path cannot do: numba's own load decides
                loaded = None
        if loaded is None:
            loaded = full(sig, target_context)
        if loaded is None:
            _compiling(cached=_FUNCTION_CACHE is not None and isinstance(cache, _FUNCTION_CACHE))
        return loaded

    cache.load_overload = load_overload


_compiled: list[bool] = []  # [True] once a compile of the package's started in this process


def _compiling(cached: bool) -> None:
    """A compile is about to start: once per process, the plain slice error and one line to the listener."""
    if _compiled:
        return
    _compiled.append(True)
    _plain_slice_shape_error()
    if cached:
        where, home = cache_dir(), os.path.expanduser("~")
        if home not in ("", os.sep) and where.startswith(home + os.sep):
            where = "~" + where[len(home):]
        first_compile.tell(f"compiling numerical code for this machine, once (up to a minute); later runs load it"
                           f" from {where}")
    else:
        first_compile.tell("compiling numerical code (no writable cache directory, so every run compiles again;"
                           " NUMBA_CACHE_DIR names one)")


def _plain_slice_shape_error() -> None:
    """numba's CPU message for ``a[...] = b`` of mismatched shapes formats both shapes into a string at run
    time. Its string code (``str`` of ints, ``join``, f-strings) is compiled into every function that assigns
    a slice from an array: about a third of the package's first compile (issue 40, docs/measured.md). Here
    that overload gives numba's generic-target message instead ("cannot assign slice from input of different
    size", the same ValueError). It applies to every function compiled in this process after the first
    compile of one of the package's functions; code loaded from the cache is unchanged."""
    try:
        from numba.core.typing.templates import builtin_registry
        from numba.np import arrayobj
    except ImportError:  # pragma: no cover - another numba
        return
    stub = getattr(arrayobj, "raise_with_shape_context", None)
    plain = getattr(arrayobj, "ol_raise_with_shape_context_generic", None)
    if stub is None or plain is None:  # pragma: no cover - a numba without the shaped message
        return
    for func, typ in list(getattr(builtin_registry, "globals", ())):
        if func is stub:
            for template in getattr(typ, "templates", ()):
                if getattr(template, "metadata", {}).get("target") == "CPU" and hasattr(template, "_overload_func"):
                    template._overload_func = staticmethod(plain)


def cached_njit(**options):
    """``njit(**options)`` with its cache in the user's cache directory (module docstring); compiled in each
    process where no cache directory can be written."""

    def wrap(func):
        dispatcher = njit(**options)(func)
        if getattr(dispatcher, "_cache", None) is None:  # NUMBA_DISABLE_JIT: the function itself
            return dispatcher
        if _FUNCTION_CACHE is not None:
            try:
                dispatcher._cache = _FUNCTION_CACHE(dispatcher.py_func)
            except RuntimeError:  # numba: "cannot cache function ...: no locator available for file ..."
                pass
        _watch_loads(dispatcher)
        return dispatcher

    return wrap
