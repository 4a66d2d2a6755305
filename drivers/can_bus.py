"""A live python-can bus (SocketCAN incl. vcan0, udp_multicast, virtual, ...) as a sample source."""

from __future__ import annotations

import time
from collections.abc import Iterator

import can

from drivers.assembler import FrameAssembler
from drivers.base import SampleSource
from drivers.signal_map import SignalMap
from online_id.errors import OnlineIdError
from online_id.samples import Sample


def open_bus(interface: str, channel: str, **kwargs) -> can.BusABC:
    """``can.Bus`` with a one-line error when the interface cannot be opened."""
    try:
        return can.Bus(interface=interface, channel=channel, **kwargs)
    except (can.CanError, OSError, ImportError, ValueError) as exc:
        hint = " (is vcan0 up? see scripts/setup-vcan.sh)" if interface == "socketcan" else ""
        raise OnlineIdError(f"cannot open CAN interface {interface}:{channel}: {exc}{hint}") from None


class CanBusSource(SampleSource):
    """Samples from a live bus.

    The stream ends when nothing arrives for ``idle_timeout_s`` after the first frame (end of
    stream), after ``start_timeout_s`` without any frame, or when the bus fails (``ended_by``
    says which); what was received until then stays usable.
    """

    def __init__(self, bus: can.BusABC, db, signal_map: SignalMap, idle_timeout_s: float = 2.0,
                 start_timeout_s: float | None = None, name: str = "bus"):
        super().__init__()
        self.bus = bus
        self.name = name
        self.assembler = FrameAssembler(db, signal_map, filter_channel=False)
        self.idle_timeout_s = idle_timeout_s
        self.start_timeout_s = start_timeout_s
        self.first_frame_wall: float | None = None
        # per sample: wall time it reached the estimator minus the receive timestamp of its last frame
        self.lag_s: list[float] = []

    def _samples(self) -> Iterator[Sample]:
        started = time.monotonic()
        last = None
        while True:
            try:
                msg = self.bus.recv(timeout=0.2)
            except (can.CanError, OSError) as exc:
                self.ended_by = f"bus lost: {exc}"
                return
            now = time.monotonic()
            if msg is None:
                if last is not None and now - last > self.idle_timeout_s:
                    self.ended_by = f"end of stream (nothing for {self.idle_timeout_s:g} s)"
                    return
                if last is None and self.start_timeout_s is not None and now - started > self.start_timeout_s:
                    self.ended_by = f"no frame within {self.start_timeout_s:g} s"
                    return
                continue
            if self.first_frame_wall is None:
                self.first_frame_wall = now
            last = now
            sample = self.assembler.feed(msg)
            if sample is not None:
                self.lag_s.append(time.time() - msg.timestamp if msg.timestamp > 1e9 else 0.0)
                yield sample

    def report(self) -> dict:
        return self.assembler.stats.to_dict()

    def problems(self) -> list[str]:
        return self.assembler.stats.problems()

    def close(self) -> None:
        try:
            self.bus.shutdown()
        except Exception as exc:  # a bus that already failed may fail again on shutdown
            raise OnlineIdError(f"{self.name}: shutdown failed: {exc}") from None
