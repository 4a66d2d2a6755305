"""Driver layer: own frames, a real car's log through its DBC, bad frames, stale signals, lost bus."""

from __future__ import annotations

import threading
import time

import can
import cantools
import numpy as np
import pytest
from online_id.drivers.assembler import FrameAssembler
from online_id.drivers.can_bus import CanBusSource
from online_id.drivers.can_log import CanLogSource, load_dbc
from online_id.drivers.csv_source import TrackRunSource
from online_id.drivers.frames import frames_from_run, load_own_dbc
from online_id.drivers.signal_map import SignalMapError, load_signal_map

from online_id.estimation import make_estimator, run_estimator
from online_id.sim.simulator import simulate
from online_id.stream.samples import samples_from_run
from online_id.vehicle import PARAMETER_NAMES, load_vehicle

QUANTUM = {"steering_wheel_angle": 1e-7, "speed": 1e-5, "yaw_rate": 1e-6, "lateral_acceleration": 1e-5,
           "roll_angle": 1e-7, "roll_rate": 1e-6}


@pytest.fixture(scope="module")
def car():
    return load_vehicle("haro2008")


@pytest.fixture(scope="module")
def short_run(car):
    return simulate(car, car.truth("track"), duration_s=2.0, seed=4).run


def _assembler(own=True):
    return FrameAssembler(load_own_dbc(), load_signal_map("online_id"))


def test_own_frames_round_trip_within_half_a_quantisation_step(short_run):
    frames = list(frames_from_run(short_run))
    assert len(frames) == 4 * len(short_run)
    asm = _assembler()
    got = [s for s in map(asm.feed, frames) if s is not None]
    ref = list(samples_from_run(short_run))
    assert len(got) == len(ref) and asm.stats.samples == len(ref)
    for name, q in QUANTUM.items():
        err = max(abs(getattr(a, name) - getattr(b, name)) for a, b in zip(got, ref))
        assert err <= q / 2 + 1e-12, (name, err)
    assert max(abs(a.time - b.time) for a, b in zip(got, ref)) <= 0.5e-6


def test_track_run_source_yields_the_csv_samples(tmp_path, short_run):
    from online_id.io.tracklog import write_track_run

    path = write_track_run(short_run, tmp_path / "r.csv")
    with TrackRunSource(path) as src:
        samples = list(src)
    assert len(samples) == len(short_run) and src.ended_by == "end of data"


def test_rav4_log_decodes_to_plausible_samples_with_the_iso_sign(rav4_paths):
    log, dbc = rav4_paths
    src = CanLogSource(log, load_dbc(dbc), load_signal_map("toyota_rav4_2017"))
    samples = list(src)
    assert len(samples) == 4974 and src.ended_by == "end of data"
    a = np.array([(s.time, s.steering_wheel_angle, s.speed, s.yaw_rate, s.lateral_acceleration) for s in samples])
    t, dH, V, r, ay = a.T
    assert np.all(np.diff(t) > 0)
    assert 8.0 < V.min() and V.max() < 20.5  # 29-73 km/h
    assert np.abs(dH).max() < np.deg2rad(6) and np.abs(r).max() < np.deg2rad(3) and np.abs(ay).max() < 1.5
    # ISO 8855: a_y ≈ V r in a turn. The raw ACCEL_Y has the opposite sign; the map negates it.
    slope = np.polyfit(V * r, ay, 1)[0]
    assert 0.5 < slope < 1.2, slope
    assert np.corrcoef(dH, r)[0, 1] > 0.5  # yaw follows steering: both positive to the left
    report = src.report()
    assert report["unknown_frames"] > 40000 and report["other_channel"] == 45000


def test_estimator_on_the_rav4_log_stays_stable_and_says_what_it_did_not_learn(rav4_paths):
    log, dbc = rav4_paths
    car = load_vehicle("rav4_2017")
    src = CanLogSource(log, load_dbc(dbc), load_signal_map("toyota_rav4_2017"))
    res = run_estimator(make_estimator(car, "ekf"), src)
    v = res.parameters.to_vector()
    assert np.all(np.isfinite(v)) and np.all(np.isfinite(res.std))
    assert res.events.get("resets", 0) == 0
    not_informed = {n for n, ok in res.informed.items() if not ok}
    assert {"Mzz", "Mxx", "Aro", "Kro", "b1", "b2"} <= not_informed, res.informed
    prior = car.prior.to_vector()
    for i, n in enumerate(PARAMETER_NAMES):
        if n in not_informed:  # kept near the prior: within its prior σ
            assert abs(np.log(v[i] / prior[i])) < res.prior_relative_std[i], n


def test_unknown_ids_are_ignored_and_counted(short_run):
    asm = _assembler()
    asm.feed(can.Message(arbitration_id=0x7FF, data=bytes(8), is_extended_id=False))
    asm.feed(can.Message(arbitration_id=0x7FF, data=bytes(8), is_extended_id=False))
    asm.feed(can.Message(arbitration_id=0x123, data=bytes(3), is_extended_id=False))
    assert asm.stats.unknown_ids == {"0x7FF": 2, "0x123": 1}
    assert "0x7FF (2)" in asm.stats.problems()[0]


def test_wrong_length_and_undecodable_frames_are_counted_by_id():
    asm = _assembler()
    assert asm.feed(can.Message(arbitration_id=0x102, data=bytes(5), is_extended_id=False)) is None
    assert asm.stats.wrong_length == {"0x102": 1}
    dbc = cantools.database.load_string(
        'VERSION ""\nNS_ :\nBS_:\nBU_: X\n'
        'BO_ 300 MUXED: 8 X\n SG_ MUX M : 0|8@1+ (1,0) [0|255] "" X\n SG_ A m1 : 8|16@1- (1,0) [0|0] "" X\n'
        'BO_ 301 SPD: 8 X\n SG_ V : 0|16@1+ (0.01,0) [0|0] "" X\n', "dbc")
    from online_id.drivers.signal_map import SignalMap, SignalSpec

    m = SignalMap(name="t", trigger="SPD", signals={"speed": SignalSpec("SPD", ("V",)),
                                                    "steering_wheel_angle": SignalSpec("MUXED", ("A",))},
                  messages=("MUXED", "SPD"), source="test")
    asm = FrameAssembler(dbc, m)
    asm.feed(can.Message(arbitration_id=300, data=bytes([5, 2, 0, 0, 0, 0, 0, 0]), is_extended_id=False))
    assert asm.stats.undecodable == {"0x12C": 1}
    assert any("undecodable payload" in p and "0x12C" in p for p in asm.stats.problems())


def test_a_signal_that_stops_arriving_is_reported_stale_and_left_out(short_run):
    frames = list(frames_from_run(short_run))
    roll_id = load_own_dbc().get_message_by_name("OID_ROLL").frame_id
    steer_id = load_own_dbc().get_message_by_name("OID_STEERING").frame_id
    # roll frames stop after 0.5 s; steering frames stop after 1.5 s
    kept = [f for f in frames if not (f.arbitration_id == roll_id and f.timestamp > 0.5)
            and not (f.arbitration_id == steer_id and f.timestamp > 1.5)]
    asm = _assembler()
    out = [s for s in map(asm.feed, kept) if s is not None]
    assert asm.stats.stale["roll_angle"] > 900 and asm.stats.stale["roll_rate"] > 900
    assert all(s.roll_angle is None for s in out if s.time > 0.6)
    assert all(s.roll_angle is not None for s in out if s.time < 0.5)
    assert asm.stats.incomplete_samples > 400  # no steering: no sample
    assert max(s.time for s in out) < 1.6
    assert any("stale signal(s)" in p and "roll_angle" in p for p in asm.stats.problems())


def test_a_missing_frame_does_not_lend_its_previous_values_to_the_next_sample(short_run):
    frames = list(frames_from_run(short_run))
    yaw_id = load_own_dbc().get_message_by_name("OID_YAW_LAT").frame_id
    dropped = [f for i, f in enumerate(frames) if not (f.arbitration_id == yaw_id and i // 4 == 100)]
    asm = _assembler()
    out = [s for s in map(asm.feed, dropped) if s is not None]
    assert out[100].yaw_rate is None and out[100].lateral_acceleration is None
    assert asm.stats.counter_mismatch["yaw_rate"] == 1


def test_signal_map_errors_name_the_problem(tmp_path):
    p = tmp_path / "m.toml"
    p.write_text('trigger = "X"\n[signals.yaw]\nmessage = "M"\nsignal = "S"\n')
    with pytest.raises(SignalMapError, match="unknown canonical signal 'yaw'"):
        load_signal_map(p)
    p.write_text('trigger = "KINEMATICS"\n[signals.speed]\nmessage = "SPEED"\nsignal = "SPEED"\n')
    with pytest.raises(SignalMapError, match="missing required signal"):
        load_signal_map(p)
    with pytest.raises(SignalMapError, match="no such signal map"):
        load_signal_map(tmp_path / "nope.toml")


def test_a_bus_that_disappears_ends_the_run_with_results_kept(car, short_run, record_bus):
    channel = f"lost-bus-{time.monotonic_ns()}"
    # frames keep the run's timestamps (as tests/test_loss.py): stamped with the wall clock, a sender held up
    # >0.1 s inside a sample (numba loading the filter's loops beside it) made that sample stale: 499 of 500
    rx = can.Bus(interface="virtual", channel=channel, preserve_timestamps=True)
    tx = can.Bus(interface="virtual", channel=channel, preserve_timestamps=True)
    record_bus(f"python-can virtual:{channel} (in-process; the bus is shut down mid-run)")
    source = CanBusSource(rx, load_own_dbc(), load_signal_map("online_id"), name="virtual")
    frames = list(frames_from_run(short_run))

    def sender():
        for f in frames[:2000]:
            tx.send(f)
        # the bus goes away once the listener has read every frame (a fixed sleep raced a listener short of CPU)
        deadline = time.monotonic() + 60
        while not rx.queue.empty() and time.monotonic() < deadline:
            time.sleep(0.01)
        time.sleep(0.3)  # the last frames decoded and their sample made
        rx.shutdown()  # the receiving bus goes away under the listener

    th = threading.Thread(target=sender)
    th.start()
    res = run_estimator(make_estimator(car, "ekf"), source)
    th.join()
    tx.shutdown()
    assert source.ended_by.startswith("bus lost"), source.ended_by
    assert res.samples == 500 and np.all(np.isfinite(res.parameters.to_vector())), source.assembler.stats


def test_the_old_names_drivers_and_replay_warn_and_give_the_same_modules():
    """drivers/ and replay/ install as online_id.drivers and online_id.replay (issue 37); ``import drivers`` and
    ``import replay`` (and their submodules) still work for one release, with a DeprecationWarning, and give the
    same module objects (a class is the same class under either name). Run in a fresh process from the checkout,
    where the folders themselves are on the path."""
    import subprocess
    import sys
    from pathlib import Path

    code = ("import warnings, online_id.drivers.csv_source as new, online_id.replay.player as player\n"
            "with warnings.catch_warnings(record=True) as seen:\n"
            "    warnings.simplefilter('always')\n"
            "    import drivers, replay.player\n"
            "    from drivers.csv_source import TrackRunSource\n"
            "assert drivers.__name__ == 'online_id.drivers' and replay.player is player\n"
            "assert TrackRunSource is new.TrackRunSource\n"
            "assert [w.category for w in seen] == [DeprecationWarning] * 2, [str(w.message) for w in seen]\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                          cwd=Path(__file__).resolve().parents[1])
    assert done.returncode == 0, done.stderr
