"""Interrupts that come through compiled code (kept apart from util/jit.py: the CLI imports this at start-up,
and numba must not be imported there)."""

from __future__ import annotations


def interrupt_inside(exc: BaseException) -> KeyboardInterrupt | None:
    """The KeyboardInterrupt (Ctrl-C, or SIGTERM/SIGHUP through online_id/cli/termination.py) behind ``exc``, if any.

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
