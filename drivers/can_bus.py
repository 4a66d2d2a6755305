"""A live python-can bus (SocketCAN incl. vcan0, udp_multicast, virtual, ...) as a sample source."""

from __future__ import annotations

import queue
import socket
import sys
import threading
import time
from collections.abc import Iterator

import can

from drivers.assembler import FrameAssembler
from drivers.base import SampleSource
from drivers.signal_map import SignalMap
from online_id.errors import OnlineIdError
from online_id.samples import Sample

#: Receive buffer asked of a SocketCAN socket [bytes]: a few seconds of a busy bus.
SOCKET_RCVBUF = 8 * 1024 * 1024
#: Linux's SO_RCVBUFFORCE (asm-generic/socket.h); Python's socket module does not export it.
_SO_RCVBUFFORCE = 33


def open_bus(interface: str, channel: str, **kwargs) -> can.BusABC:
    """``can.Bus`` with a one-line error when the interface cannot be opened."""
    try:
        bus = can.Bus(interface=interface, channel=channel, **kwargs)
    except (can.CanError, OSError, ImportError, ValueError) as exc:
        hint = " (is vcan0 up? see scripts/setup-vcan.sh)" if interface == "socketcan" else ""
        raise OnlineIdError(f"cannot open CAN interface {interface}:{channel}: {exc}{hint}") from None
    _enlarge_receive_buffer(bus)
    return bus


def _enlarge_receive_buffer(bus) -> None:
    """Best effort: a larger kernel receive buffer absorbs bursts while the estimator is busy.

    SO_RCVBUFFORCE (root or CAP_NET_ADMIN) goes past ``net.core.rmem_max``; otherwise SO_RCVBUF asks
    for as much as that limit allows.
    """
    sock = getattr(bus, "socket", None)
    if not isinstance(sock, socket.socket):
        return
    force = _SO_RCVBUFFORCE if sys.platform.startswith("linux") else None
    for opt in (force, socket.SO_RCVBUF):
        if opt is None:
            continue
        try:
            sock.setsockopt(socket.SOL_SOCKET, opt, SOCKET_RCVBUF)
            return
        except OSError:
            continue


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
        # A reader thread drains the bus into a queue: slow decoding or estimation then shows up as
        # lag, not as frames lost to an overflowing socket receive buffer.
        frames: queue.Queue = queue.Queue()
        stop = threading.Event()
        reader = threading.Thread(target=self._read, args=(frames, stop), name="can-reader", daemon=True)
        reader.start()
        started = time.monotonic()
        last = None
        try:
            while True:
                try:
                    item = frames.get(timeout=0.2)
                except queue.Empty:
                    now = time.monotonic()
                    if last is not None and now - last > self.idle_timeout_s:
                        self.ended_by = f"end of stream (nothing for {self.idle_timeout_s:g} s)"
                        return
                    if last is None and self.start_timeout_s is not None and now - started > self.start_timeout_s:
                        self.ended_by = f"no frame within {self.start_timeout_s:g} s"
                        return
                    continue
                if isinstance(item, BaseException):
                    self.ended_by = f"bus lost: {item}"
                    return
                last = item[1]
                if self.first_frame_wall is None:
                    self.first_frame_wall = last
                sample = self.assembler.feed(item[0])
                if sample is not None:
                    ts = item[0].timestamp
                    self.lag_s.append(time.time() - ts if ts > 1e9 else 0.0)
                    yield sample
        finally:
            stop.set()
            reader.join(timeout=2.0)

    def _read(self, frames: queue.Queue, stop: threading.Event) -> None:
        while not stop.is_set():
            try:
                msg = self.bus.recv(timeout=0.1)
                # drain everything already waiting while this thread holds the GIL: one frame per
                # thread switch is too slow for a busy bus on a slow machine
                while msg is not None:
                    frames.put((msg, time.monotonic()))
                    msg = self.bus.recv(timeout=0.0)
            except (can.CanError, OSError, ValueError) as exc:
                frames.put(exc)
                return

    def report(self) -> dict:
        return self.assembler.stats.to_dict()

    def problems(self) -> list[str]:
        return self.assembler.stats.problems()

    def close(self) -> None:
        try:
            self.bus.shutdown()
        except Exception as exc:  # a bus that already failed may fail again on shutdown
            raise OnlineIdError(f"{self.name}: shutdown failed: {exc}") from None
