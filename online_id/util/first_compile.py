"""Who hears that a one-time compile is starting: the CLI prints one line, the library says nothing.

Kept apart from :mod:`online_id.util.jit` (which imports numba) so that the CLI can listen before any
command runs without paying numba's import at start-up (``tests/test_startup.py``).
"""

from __future__ import annotations

from collections.abc import Callable

_listener: Callable[[str], None] | None = None
_told = False


def listen(callback: Callable[[str], None] | None) -> None:
    """``callback(line)`` is called once per process, when the first compile starts (None: nobody hears)."""
    global _listener
    _listener = callback


def tell(line: str) -> None:
    """Say ``line`` to the listener, the first time only (later compiles in the same process are quiet)."""
    global _told
    if _told:
        return
    _told = True
    if _listener is not None:
        _listener(line)
