"""Play frames onto a CAN bus at real-time rate (in the manner of python-can's ``can.player``).

Frames carry their log time in ``timestamp``; frame k is sent at
t_start + (timestamp_k − timestamp_0) / speed. The player sleeps until about a
millisecond before each send time and spins for the rest, so sends land close to
their schedule; how late each one was is measured and reported (p50, p99, max).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass

import can
import numpy as np

#: Sleep until this long before a frame's send time, then spin.
SPIN_S = 0.0015


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

    def summary(self) -> str:
        return (f"{self.frames} frames in {self.duration_s:.2f} s ({self.loops} pass(es)); lateness p50"
                f" {self.lateness_p50_s * 1e3:.3f} ms, p99 {self.lateness_p99_s * 1e3:.3f} ms,"
                f" max {self.lateness_max_s * 1e3:.3f} ms; ended by {self.ended_by}")

    def to_dict(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


def play(frames: Callable[[], Iterable[can.Message]], bus: can.BusABC, speed: float = 1.0, loop: bool = False,
         max_loops: int | None = None) -> TimingReport:
    """Send ``frames()`` (a callable, so a loop can start it again) on ``bus`` at ``speed`` × real time."""
    if speed <= 0:
        raise ValueError("speed must be positive")
    lateness: list[float] = []
    sent = 0
    loops = 0
    ended_by = "end of data"
    t_start = time.perf_counter()
    try:
        while True:
            loops += 1
            t0 = None
            base = time.perf_counter()
            for msg in frames():
                if t0 is None:
                    t0 = msg.timestamp
                due = base + (msg.timestamp - t0) / speed
                now = time.perf_counter()
                if due - now > SPIN_S:
                    time.sleep(due - now - SPIN_S)
                while time.perf_counter() < due:
                    pass
                lateness.append(time.perf_counter() - due)
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
    except KeyboardInterrupt:
        ended_by = "interrupted"
    late = np.array(lateness) if lateness else np.zeros(1)
    return TimingReport(frames=sent, loops=loops, duration_s=time.perf_counter() - t_start,
                        lateness_p50_s=float(np.percentile(late, 50)), lateness_p99_s=float(np.percentile(late, 99)),
                        lateness_max_s=float(late.max()), ended_by=ended_by)
