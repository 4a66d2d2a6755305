"""Loss on a live stream is counted from COUNTER and SAMPLE_TIME gaps and reported as it starts (issue 17)."""

from __future__ import annotations

import threading
import time

import can
import pytest
from online_id.drivers.assembler import FrameAssembler
from online_id.drivers.can_bus import CanBusSource
from online_id.drivers.frames import frames_from_run, load_own_dbc
from online_id.drivers.signal_map import load_signal_map

from online_id.estimation import make_estimator, run_estimator
from online_id.sim.simulator import simulate
from online_id.vehicle import load_vehicle

FRAMES_PER_SAMPLE = 4


@pytest.fixture(scope="module")
def car():
    return load_vehicle("haro2008")


@pytest.fixture(scope="module")
def frames(car):
    return list(frames_from_run(simulate(car, car.truth("track"), duration_s=2.0, seed=4).run))


def _feed(frames):
    asm = FrameAssembler(load_own_dbc(), load_signal_map("online_id"))
    out = [s for s in map(asm.feed, frames) if s is not None]
    return asm.stats, out


def test_whole_samples_lost_are_counted_from_the_sample_time_even_past_the_counter_wrap(frames):
    lost = set(range(100, 110)) | {500, 900} | set(range(1200, 1500))  # 300 in a row: COUNTER wraps
    stats, out = _feed([f for i, f in enumerate(frames) if i // FRAMES_PER_SAMPLE not in lost])
    assert len(out) == 2000 - len(lost)
    assert stats.lost_samples == len(lost)
    assert stats.first_loss_time == pytest.approx(0.110)
    assert stats.lost_by_signal["yaw_rate"] == len(lost)
    # the counter says 12 + (300 mod 256) - a run of 256 per message hides from an 8-bit counter
    assert stats.lost_frames["OID_YAW_LAT"] == 12 + 300 % 256
    assert "312 sample(s) lost" in stats.loss_line()


def test_a_lost_frame_costs_its_signals_not_the_sample(frames):
    yaw = load_own_dbc().get_message_by_name("OID_YAW_LAT").frame_id
    dropped = {10, 11, 700}
    stats, out = _feed([f for i, f in enumerate(frames)
                        if not (f.arbitration_id == yaw and i // FRAMES_PER_SAMPLE in dropped)])
    assert len(out) == 2000 and stats.lost_samples == 0
    assert stats.lost_frames == {"OID_YAW_LAT": 3}
    assert stats.lost_by_signal["yaw_rate"] == 3 and stats.lost_by_signal["lateral_acceleration"] == 3
    assert stats.lost_by_signal["roll_angle"] == 0
    assert [s.yaw_rate is None for s in out].count(True) == 3


def test_a_frame_is_never_used_for_two_samples_however_the_counter_wraps(frames):
    """Sample 300 complete, the 255 after it lost, and the yaw frame of sample 556 lost: 556 has sample 300's
    COUNTER, and 300's yaw frame must not stand in for its own (at 10x speed, 256 samples take 26 ms: inside
    the 50 ms stale window, which alone would not catch it)."""
    yaw = load_own_dbc().get_message_by_name("OID_YAW_LAT").frame_id
    kept = []
    for i, f in enumerate(frames):
        k = i // FRAMES_PER_SAMPLE
        if 300 < k < 556 or (k == 556 and f.arbitration_id == yaw):
            continue
        kept.append(can.Message(timestamp=f.timestamp / 10, arbitration_id=f.arbitration_id, data=f.data,
                                is_extended_id=False))
    stats, out = _feed(kept)
    (after,) = [s for s in out if abs(s.time - 0.556) < 1e-6]
    assert after.yaw_rate is None and stats.counter_mismatch["yaw_rate"] == 1
    assert stats.lost_samples == 255


def _virtual_pair():
    """Frames keep the run's own timestamps: the virtual bus would stamp them with the wall clock, and a
    sender thread held up > stale_after_s between two frames of one sample (a loaded machine) would then
    make that sample stale and incomplete - one sample fewer, for a reason that has nothing to do with loss."""
    channel = f"loss-{time.monotonic_ns()}"
    return (can.Bus(interface="virtual", channel=channel, preserve_timestamps=True),
            can.Bus(interface="virtual", channel=channel, preserve_timestamps=True))


def test_the_live_source_warns_when_loss_starts_and_when_no_frame_makes_a_sample(car, frames):
    rx, tx = _virtual_pair()
    told = []
    source = CanBusSource(rx, load_own_dbc(), load_signal_map("online_id"), idle_timeout_s=0.5, name="virtual",
                          on_problem=told.append)
    lost = set(range(400, 420))

    def sender():
        for i, f in enumerate(frames):
            if i == 4 * 250 + 1:  # a sender held up inside a sample (a loaded machine): no sample may be lost
                time.sleep(0.15)
            if i // FRAMES_PER_SAMPLE not in lost:
                tx.send(f)

    th = threading.Thread(target=sender)
    th.start()
    res = run_estimator(make_estimator(car), source)
    th.join()
    tx.shutdown()
    rx.shutdown()
    assert res.samples == 1980 and source.assembler.stats.lost_samples == 20
    assert len(told) == 1 and "20 sample(s) lost" in told[0] and "from t = 0.420 s" in told[0]


def test_frames_that_never_make_a_sample_are_reported_within_seconds_not_at_the_end(frames):
    rx, tx = _virtual_pair()
    told = []
    source = CanBusSource(rx, load_own_dbc(), load_signal_map("online_id"), idle_timeout_s=30, name="virtual",
                          on_problem=told.append)
    started = time.monotonic()
    stop = threading.Event()

    def sender():  # a foreign bus: IDs the map does not know, until told to stop
        i = 0
        while not stop.is_set():
            tx.send(can.Message(arbitration_id=0x300 + i % 3, data=bytes(8), is_extended_id=False))
            i += 1
            time.sleep(0.0005)

    th = threading.Thread(target=sender)
    th.start()
    it = iter(source)
    reader = threading.Thread(target=lambda: next(it, None), daemon=True)
    reader.start()
    while not told and time.monotonic() - started < 20:
        time.sleep(0.05)
    stop.set()
    th.join()
    rx.shutdown()
    tx.shutdown()
    assert told, "no warning while frames kept arriving"
    assert time.monotonic() - started < 10
    assert "none made a sample" in told[0] and "0x300" in told[0]


def test_nothing_before_the_start_timeout_is_said_apart_from_an_ended_stream():
    rx, tx = _virtual_pair()
    source = CanBusSource(rx, load_own_dbc(), load_signal_map("online_id"), start_timeout_s=0.3, name="virtual")
    assert list(source) == []
    assert source.nothing_arrived and source.ended_by == "no frame within 0.3 s"
    rx.shutdown()
    tx.shutdown()
