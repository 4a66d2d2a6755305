"""A live python-can bus (SocketCAN incl. vcan0, udp_multicast, virtual, ...) as a sample source."""

from __future__ import annotations

import queue
import socket
import sys
import threading
import time
from collections.abc import Iterator

import can
from online_id.drivers.assembler import FrameAssembler
from online_id.drivers.base import SampleSource
from online_id.drivers.signal_map import SignalMap

from online_id.errors import OnlineIdError
from online_id.stream.samples import Sample
from online_id.util.reservoir import Reservoir

#: python-can interfaces whose buses meet only inside one process, and what to use across processes instead:
#: ``listen`` in one terminal and ``replay`` in another never meet on ``virtual`` (issue 39: listen waited for
#: its start timeout with no word why).
IN_PROCESS_ONLY: dict[str, str] = {
    "virtual": "python-can's virtual bus connects only buses opened in the same process: frames sent by another"
               " process (a replay, a logger) never arrive; across processes use --interface udp_multicast"
               " --channel 239.74.163.2 (or socketcan on Linux's vcan0, scripts/setup-vcan.sh)",
}


def in_process_only(interface: str) -> str | None:
    """Why ``interface`` does not cross processes, and what does, or None."""
    return IN_PROCESS_ONLY.get(str(interface).lower())


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
    sock = _socket_of(bus)
    if sock is None:
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


def _socket_of(bus) -> socket.socket | None:
    """The receiving socket of a SocketCAN bus (``bus.socket``) or of python-can's udp_multicast
    (``bus._multicast._socket``: without a larger buffer there, about 280 datagrams fill the
    default 208 KiB and a 5x replay lost 23 % of its frames)."""
    for sock in (getattr(bus, "socket", None), getattr(getattr(bus, "_multicast", None), "_socket", None)):
        if isinstance(sock, socket.socket):
            return sock
    return None


def receive_buffer_bytes(bus) -> int | None:
    """The kernel receive buffer the bus's socket got [bytes] (None: not a socket bus)."""
    sock = _socket_of(bus)
    try:
        return None if sock is None else sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
    except OSError:
        return None


#: Frames the reader thread hands over at once: one queue operation per batch, not per frame.
READ_BATCH = 256
#: Frames the reader thread holds for the estimator at most: 100,000, 25 s of online-id's frames at 1 kHz
#: (4 a sample) and about 23 MB. An estimator that has fallen this far behind a live bus stops the reader, and
#: frames wait in the socket's receive buffer, where the kernel drops what does not fit: counted as lost
#: samples, as any loss. Without a bound, a listener slower than its bus for good grows without limit; with
#: 40,000 (10 s), a 30-minute soak on a machine at load 9 lost 725 samples of 1.8 million to it.
MAX_BACKLOG_FRAMES = 100_000
#: How often a stopped reader looks whether the estimator has caught up [s].
BACKLOG_WAIT_S = 0.05
#: Frames seen without a single sample before the map is reported as not matching the bus (a few
#: tenths of a second of online-id's 4 kHz frame rate, a second of a car's bus) ...
NO_SAMPLE_FRAMES = 2000
#: ... or this long after the first frame [s], whichever comes first.
NO_SAMPLE_S = 2.0


class CanBusSource(SampleSource):
    """Samples from a live bus.

    The stream ends when nothing arrives for ``idle_timeout_s`` after the first frame (end of
    stream), after ``start_timeout_s`` without any frame (``nothing_arrived`` is then True), or
    when the bus fails (``ended_by`` says which); what was received until then stays usable.
    ``on_problem(line)`` is called at once when frames arrive but none makes a sample (a wrong
    DBC or map) and when samples start to be lost.
    """

    def __init__(self, bus: can.BusABC, db, signal_map: SignalMap, idle_timeout_s: float = 2.0,
                 start_timeout_s: float | None = None, name: str = "bus", on_problem=None):
        super().__init__()
        self.bus = bus
        self.name = name
        self.assembler = FrameAssembler(db, signal_map, filter_channel=False)
        self.idle_timeout_s = idle_timeout_s
        self.start_timeout_s = start_timeout_s
        self.first_frame_wall: float | None = None
        self.nothing_arrived = False
        self.receive_buffer_bytes = receive_buffer_bytes(bus)
        self.on_problem = on_problem or (lambda line: None)
        self._told_no_sample = False
        self._told_loss = False
        self._frames_read = 0  # by the reader thread (written there only)
        self._frames_taken = 0  # by the estimator's side (written there only): the backlog is the difference
        self.backlog_stops = 0  # times the reader stopped at MAX_BACKLOG_FRAMES
        self._told_backlog = False
        # per sample: wall time it reached the estimator minus the receive timestamp of its last frame; every
        # sample's up to 100 s at 1 kHz, then a uniform sample of that many (bounded memory over hours)
        self.lag_s = Reservoir()

    def _samples(self) -> Iterator[Sample]:
        # A reader thread drains the bus into a queue: slow decoding or estimation then shows up as
        # lag, not as frames lost to an overflowing socket receive buffer.
        frames: queue.Queue = queue.Queue()
        stop = threading.Event()
        reader = threading.Thread(target=self._read, args=(frames, stop), name="can-reader", daemon=True)
        reader.start()
        started = time.monotonic()
        last = None
        stats = self.assembler.stats
        feed = self.assembler.feed
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
                        self.nothing_arrived = True
                        return
                    self._check_early(now)
                    continue
                if isinstance(item, BaseException):
                    self.ended_by = f"bus lost: {item}"
                    return
                batch, last = item
                self._frames_taken += len(batch)
                if self.first_frame_wall is None:
                    self.first_frame_wall = last
                if self.backlog_stops and not self._told_backlog:
                    self._told_backlog = True
                    self.on_problem(f"the estimator fell {MAX_BACKLOG_FRAMES} frames behind the bus; frames wait in"
                                    " the socket's buffer, and what does not fit is lost (counted)")
                for msg in batch:
                    sample = feed(msg)
                    if sample is not None:
                        ts = msg.timestamp
                        self.lag_s.append(time.time() - ts if ts > 1e9 else 0.0)
                        if stats.lost_samples and not self._told_loss:
                            self._told_loss = True
                            self.on_problem(stats.loss_line() + " so far; the estimate bridges the gaps")
                        yield sample
                self._check_early(last)
        finally:
            stop.set()
            reader.join(timeout=2.0)

    def _check_early(self, now: float) -> None:
        """Frames but no sample for NO_SAMPLE_FRAMES frames or NO_SAMPLE_S seconds: say so now, not at the end."""
        st = self.assembler.stats
        if self._told_no_sample or st.samples or self.first_frame_wall is None:
            return
        if st.frames >= NO_SAMPLE_FRAMES or now - self.first_frame_wall >= NO_SAMPLE_S:
            self._told_no_sample = True
            why = "; ".join(st.problems()) or "no trigger frame or no steering and speed among them"
            self.on_problem(f"{st.frames} frame(s) received but none made a sample (is --dbc/--signals the"
                            f" bus's?): {why}")

    def _read(self, frames: queue.Queue, stop: threading.Event) -> None:
        recv = self.bus.recv
        while not stop.is_set():
            if self._frames_read - self._frames_taken >= MAX_BACKLOG_FRAMES:  # bounded memory: see the constant
                self.backlog_stops += 1
                stop.wait(BACKLOG_WAIT_S)
                continue
            try:
                msg = recv(timeout=0.1)
                # drain everything already waiting while this thread holds the GIL, in batches: one
                # frame per thread switch (or per queue operation) is too slow for a busy bus
                while msg is not None:
                    batch = [msg]
                    while len(batch) < READ_BATCH:
                        msg = recv(timeout=0.0)
                        if msg is None:
                            break
                        batch.append(msg)
                    else:  # a full batch: more may be waiting, unless the backlog is at its bound
                        full = self._frames_read + len(batch) - self._frames_taken >= MAX_BACKLOG_FRAMES
                        msg = None if full else recv(timeout=0.0)
                    self._frames_read += len(batch)
                    frames.put((batch, time.monotonic()))
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
