"""Play frames onto a CAN bus at real-time rate (in the manner of python-can's ``can.player``).

Frames carry their log time in ``timestamp``; frame k is sent at
t_start + (timestamp_k − timestamp_0) / speed. The player sleeps until about a
millisecond before each send time and spins for the rest, so sends land close to
their schedule; how late each one was is measured and reported (p50, p99, max, and
the log time of the worst).

Frames are prepared ahead: up to :data:`LOOKAHEAD` of them are drawn from the source
(encoded, for a track run) in the idle time before each send, never in the
millisecond before a frame is due, so the frames of one sample all leave together
instead of each waiting for the encoding of the next. The clock starts once the
first frames are ready, and the objects that exist when playing starts (a loaded
log) are frozen out of Python's cyclic garbage collector: a full collection over
them is a pause of tens of milliseconds on a slow machine.
"""

from __future__ import annotations

import gc
import os
import time
from array import array
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass

import can
import numpy as np

from online_id.util.interrupts import interrupt_inside

#: Sleep until this long before a frame's send time, then spin.
SPIN_S = 0.0015
#: Frames drawn from the source ahead of their send time (bounded, so a long log is not all in memory).
LOOKAHEAD = 512
#: Stop drawing frames ahead this long before the next one is due (one draw can take ~1 ms when slow).
FILL_MARGIN_S = 0.003


@dataclass
class TimingReport:
    """Frames sent and how late they went out [s] (negative never happens: the player waits)."""

    frames: int
    loops: int
    duration_s: float
    lateness_p50_s: float
    lateness_p99_s: float
    lateness_max_s: float
    ended_by: str
    #: log time [s] from the start of the pass at which the latest frame was due
    lateness_max_at_s: float = 0.0

    def summary(self) -> str:
        return (f"{self.frames} frames in {self.duration_s:.2f} s ({self.loops} pass(es)); lateness p50"
                f" {self.lateness_p50_s * 1e3:.3f} ms, p99 {self.lateness_p99_s * 1e3:.3f} ms,"
                f" max {self.lateness_max_s * 1e3:.3f} ms (at {self.lateness_max_at_s:.2f} s);"
                f" ended by {self.ended_by}")

    def to_dict(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


def play(frames: Callable[[], Iterable[can.Message]], bus: can.BusABC, speed: float = 1.0, loop: bool = False,
         max_loops: int | None = None) -> TimingReport:
    """Send ``frames()`` (a callable, so a loop can start it again) on ``bus`` at ``speed`` × real time."""
    if speed <= 0:
        raise ValueError("speed must be positive")
    lateness = _LatenessLog()
    sent = 0
    loops = 0
    ended_by = "end of data"
    t_start = time.perf_counter()
    gc.freeze()  # what exists now (a loaded log) is never scanned by the collector while playing
    try:
        while True:
            loops += 1
            ahead = _Ahead(iter(frames()))
            ahead.fill(until=float("inf"))
            base = time.perf_counter()
            t0 = None
            while (msg := ahead.next()) is not None:
                if t0 is None:
                    t0 = msg.timestamp
                due = base + (msg.timestamp - t0) / speed
                ahead.fill(until=due - SPIN_S - FILL_MARGIN_S)
                now = time.perf_counter()
                if due - now > SPIN_S:
                    time.sleep(due - now - SPIN_S)
                while time.perf_counter() < due:
                    pass
                lateness.add(time.perf_counter() - due, msg.timestamp - t0)
                try:
                    bus.send(msg)
                except (can.CanError, OSError) as exc:
                    ended_by = f"bus lost: {exc}"
                    raise StopIteration from None
                sent += 1
            if not loop or (max_loops is not None and loops >= max_loops):
                break
    except StopIteration:
        pass
    except (KeyboardInterrupt, SystemError) as exc:
        if interrupt_inside(exc) is None:  # a SystemError not from a signal in compiled code
            raise
        ended_by = "interrupted"
    finally:
        gc.unfreeze()
    late = lateness.values()
    return TimingReport(frames=sent, loops=loops, duration_s=time.perf_counter() - t_start,
                        lateness_p50_s=float(np.percentile(late, 50)), lateness_p99_s=float(np.percentile(late, 99)),
                        lateness_max_s=lateness.max, ended_by=ended_by, lateness_max_at_s=lateness.max_at)


#: Lateness values kept for the percentiles: every frame up to this many, then a uniform sample of
#: this size (8 MB), so a --loop run of hours stays bounded. The maximum is always exact.
KEEP_LATENESS = 1_000_000


class _LatenessLog:
    """Every frame's lateness up to KEEP_LATENESS, then a reservoir sample (Vitter's algorithm R)."""

    def __init__(self):
        self.kept = array("d")
        self.seen = 0
        self.max, self.max_at = 0.0, 0.0
        self._rng = np.random.default_rng(0)
        self._draws, self._next = np.empty(0), 0

    def add(self, late: float, at: float) -> None:
        self.seen += 1
        if late > self.max or self.seen == 1:
            self.max, self.max_at = late, at
        if len(self.kept) < KEEP_LATENESS:
            self.kept.append(late)
            return
        if self._next == len(self._draws):  # uniform numbers in batches: one call a frame is too slow
            self._draws, self._next = self._rng.random(4096), 0
        j = int(self._draws[self._next] * self.seen)
        self._next += 1
        if j < len(self.kept):
            self.kept[j] = late

    def values(self) -> np.ndarray:
        return np.frombuffer(self.kept) if len(self.kept) else np.zeros(1)


def raise_priority(step: int = 10) -> str:
    """Best effort: lower this process's niceness by ``step`` so a busy machine (a listener decoding
    and filtering on the same cores) delays the sends less. Needs the privilege to do so (root or
    CAP_SYS_NICE); without it nothing changes. Returns what happened, for the report."""
    try:
        before = os.nice(0)
        after = os.nice(-step)
    except (OSError, AttributeError):
        return "normal (not permitted to raise it)"
    return f"raised: niceness {before} -> {after}"


class _Ahead:
    """Frames drawn from an iterator ahead of use, into a bounded buffer."""

    def __init__(self, it):
        self.it, self.buf, self.done = it, deque(), False

    def fill(self, until: float) -> None:
        """Draw frames until the buffer is full, the source ends or the clock passes ``until``."""
        while not self.done and len(self.buf) < LOOKAHEAD and time.perf_counter() < until:
            self._draw()

    def next(self) -> can.Message | None:
        """The next frame (drawn now when none is ready), or None at the end of the source."""
        if not self.buf and not self.done:
            self._draw()
        return self.buf.popleft() if self.buf else None

    def _draw(self) -> None:
        try:
            self.buf.append(next(self.it))
        except StopIteration:
            self.done = True
