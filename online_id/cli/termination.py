"""SIGTERM and SIGHUP end a run the way Ctrl-C does: what was computed is kept, printed and written.

SIGTERM is what CI runners, systemd and ``docker stop`` send; SIGHUP what a closed SSH session
sends. Python's default for both is to die on the spot, losing everything. Inside
:func:`signals_interrupt`, SIGINT, SIGTERM and SIGHUP raise :class:`Interrupted` (a
``KeyboardInterrupt``, so every loop that already stops cleanly on Ctrl-C stops the same way),
and :func:`exit_status` gives 128 + the signal's number (130, 143, 129).

Only the first signal raises: the run is then already ending and writing its results, and a
second SIGTERM or SIGHUP (a session closing sends both) must not cut that short. A second
SIGINT still raises: a user pressing Ctrl-C again wants out now. After SIGHUP the terminal is
gone, so writing to it may fail; stdout and stderr then swallow those errors, so that the
files are still written.
"""

from __future__ import annotations

import signal
import sys
from collections.abc import Iterator
from contextlib import contextmanager

#: The signals that end a run cleanly (those this platform has).
HANDLED = tuple(getattr(signal, n) for n in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, n))

_received: list[int] = []


class Interrupted(KeyboardInterrupt):
    """A run ended by a signal; ``signum`` says which."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def received() -> int | None:
    """The first signal received inside :func:`signals_interrupt`, or None."""
    return _received[0] if _received else None


def exit_status() -> int:
    """128 + the signal that ended the run (130 for Ctrl-C, also when Python raised it itself)."""
    return 128 + (received() or signal.SIGINT)


def signal_name() -> str:
    return signal.Signals(received() or signal.SIGINT).name


def _handler(signum, frame) -> None:
    first = not _received
    _received.append(signum)
    if signum == getattr(signal, "SIGHUP", None):
        _quiet_terminal()
    if first or signum == signal.SIGINT:
        raise Interrupted(signum)


@contextmanager
def signals_interrupt() -> Iterator[None]:
    """Within the block, SIGINT, SIGTERM and SIGHUP raise :class:`Interrupted` (main thread only:
    elsewhere Python does not allow handlers, and the defaults stay)."""
    _received.clear()
    previous = {}
    try:
        for s in HANDLED:
            previous[s] = signal.signal(s, _handler)
    except ValueError:  # not the main thread
        pass
    try:
        yield
    finally:
        for s, h in previous.items():
            signal.signal(s, h)


class _QuietStream:
    """A text stream whose write errors (a hung-up terminal: EIO) are ignored."""

    def __init__(self, stream):
        self._stream = stream

    def write(self, text):
        try:
            return self._stream.write(text)
        except (OSError, ValueError):
            return len(text)

    def flush(self):
        try:
            self._stream.flush()
        except (OSError, ValueError):
            pass

    def __getattr__(self, name):
        return getattr(self._stream, name)


def _quiet_terminal() -> None:
    for name in ("stdout", "stderr"):
        stream = getattr(sys, name)
        if stream is not None and not isinstance(stream, _QuietStream):
            setattr(sys, name, _QuietStream(stream))
