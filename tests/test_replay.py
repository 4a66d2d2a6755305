"""The real-time player (replay/player.py) on an in-process bus: order, completeness, bounded lookahead,
a lost bus, and the timing report. No assertion here depends on how fast this machine is."""

from __future__ import annotations

import can
import numpy as np
import pytest
from online_id.replay import player
from online_id.replay.player import play


class RecordingBus:
    """Records what was sent and how many frames the source had given out at that moment."""

    def __init__(self, drawn: list[int], fail_after: int | None = None):
        self.sent: list[can.Message] = []
        self.drawn_at_send: list[int] = []
        self.drawn, self.fail_after = drawn, fail_after

    def send(self, msg, timeout=None):
        if self.fail_after is not None and len(self.sent) >= self.fail_after:
            raise can.CanOperationError("Network is down")
        self.sent.append(msg)
        self.drawn_at_send.append(self.drawn[0])


def source(n: int, drawn: list[int], period_s: float = 0.0005, per_stamp: int = 4):
    def frames():
        drawn[0] = 0
        for k in range(n):
            drawn[0] += 1
            yield can.Message(timestamp=100.0 + (k // per_stamp) * period_s, arbitration_id=0x100 + k % per_stamp,
                              data=k.to_bytes(4, "little"), is_extended_id=False)
    return frames


def test_every_frame_in_order_with_the_timing_report():
    drawn = [0]
    bus = RecordingBus(drawn)
    report = play(source(2000, drawn), bus)
    assert [int.from_bytes(m.data, "little") for m in bus.sent] == list(range(2000))
    assert report.frames == 2000 and report.loops == 1 and report.ended_by == "end of data"
    assert 0 <= report.lateness_p50_s <= report.lateness_p99_s <= report.lateness_max_s
    assert 0 <= report.lateness_max_at_s <= 499 * 0.0005 + 1e-12
    assert report.duration_s >= 499 * 0.0005  # paced: never ahead of the log's own time


def test_the_source_is_drawn_ahead_but_never_more_than_the_lookahead(monkeypatch):
    monkeypatch.setattr(player, "LOOKAHEAD", 16)
    drawn = [0]
    bus = RecordingBus(drawn)
    play(source(400, drawn), bus)
    ahead = [d - (i + 1) for i, d in enumerate(bus.drawn_at_send)]
    assert max(ahead) <= 16  # bounded memory on a long log
    assert bus.drawn_at_send[0] == 16  # the first frames were ready before the clock started


def test_a_lost_bus_ends_the_run_and_keeps_the_count():
    drawn = [0]
    bus = RecordingBus(drawn, fail_after=37)
    report = play(source(400, drawn), bus)
    assert report.frames == 37 and report.ended_by.startswith("bus lost") and "Network is down" in report.ended_by


def test_loop_restarts_the_source():
    drawn = [0]
    bus = RecordingBus(drawn)
    report = play(source(40, drawn), bus, loop=True, max_loops=3)
    assert report.loops == 3 and report.frames == 120
    assert [int.from_bytes(m.data, "little") for m in bus.sent[40:80]] == list(range(40))


def test_speed_must_be_positive():
    with pytest.raises(ValueError, match="speed must be positive"):
        play(source(1, [0]), RecordingBus([0]), speed=0)


def test_raise_priority_reports_what_happened():
    text = player.raise_priority(step=0)
    assert text.startswith("raised: niceness") or text.startswith("normal (not permitted")


def test_a_long_loop_keeps_bounded_lateness_records_with_the_exact_maximum(monkeypatch):
    monkeypatch.setattr(player, "KEEP_LATENESS", 100)
    log = player._LatenessLog()
    for k in range(10_000):
        log.add(1e-4 + (k % 7) * 1e-5, k * 1e-3)
    log.add(0.5, 12.345)  # one very late frame
    for k in range(10_000):
        log.add(1e-4 + (k % 7) * 1e-5, k * 1e-3)
    assert len(log.values()) == 100 and log.seen == 20_001
    assert log.max == 0.5 and log.max_at == 12.345
    # the sample stays representative: the typical values, not the first 100 frames' alone
    assert abs(np.percentile(log.values(), 50) - 1.3e-4) <= 2e-5
