"""The source layer: every python-can log format gives the same samples and estimates as the .log, for
online-id's own frames and for the RAV4 log; channels are named alike; a log without a usable sample,
or an unreadable one, is one line and exit 2; MDF files of decoded signals are read directly."""

from __future__ import annotations

import itertools
import json
import time

import can
import numpy as np
import pytest
from online_id.drivers.channels import normalise_channel
from online_id.drivers.frames import frames_from_run
from online_id.drivers.sources import open_source

from online_id.cli.main import main
from online_id.errors import OnlineIdError
from online_id.estimation import make_estimator, run_estimator
from online_id.io.tracklog import write_track_run
from online_id.sim.simulator import simulate
from online_id.vehicle import load_vehicle

#: Formats python-can writes and reads back (as `can.logconvert` does), besides the candump .log.
FORMATS = (".asc", ".blf", ".trc", ".mf4", ".csv", ".db")
#: RAV4 frames in the test: about 3 s of the log (1,650 frames a second on two buses).
RAV4_FRAMES = 5000
#: Fields of a sample.
FIELDS = ("steering_wheel_angle", "speed", "yaw_rate", "lateral_acceleration", "roll_angle", "roll_rate")


def write_log(messages, path):
    """Write ``messages`` with python-can's own writer for the suffix of ``path``."""
    messages = list(messages)
    if path.suffix == ".db":  # SqliteWriter writes from a thread in batches: wait until all are written
        writer = can.SqliteWriter(str(path))
        for m in messages:
            writer.on_message_received(m)
        deadline = time.monotonic() + 30
        while writer.num_frames < len(messages) and time.monotonic() < deadline:
            time.sleep(0.05)
        writer.stop()
        return path
    with can.Logger(str(path)) as writer:
        for m in messages:
            writer.on_message_received(m)
    return path


def convert(src, dst):
    """`python -m can.logconvert SRC DST`: read with can.LogReader, write with can.Logger."""
    return write_log(can.LogReader(str(src)), dst)


def samples_of(path, **kw):
    with open_source(path, **kw) as src:
        return list(src), src


def assert_same_samples(a, b, time_tol):
    assert len(a) == len(b) > 0
    for f in FIELDS:
        va = np.array([getattr(s, f) if getattr(s, f) is not None else np.nan for s in a])
        vb = np.array([getattr(s, f) if getattr(s, f) is not None else np.nan for s in b])
        np.testing.assert_array_equal(va, vb, err_msg=f)
    ta, tb = np.array([s.time for s in a]), np.array([s.time for s in b])
    # .asc and .blf store times from the start of the log: compare the samples' spacing
    np.testing.assert_allclose(ta - ta[0], tb - tb[0], rtol=0, atol=time_tol)


def estimate(samples, vehicle):
    return run_estimator(make_estimator(vehicle, "ekf"), samples)


@pytest.fixture(scope="module")
def car():
    return load_vehicle("haro2008")


@pytest.fixture(scope="module")
def own_logs(tmp_path_factory, car):
    """A 3 s simulated run at 200 Hz as online-id's frames, in every format, converted from the .log."""
    d = tmp_path_factory.mktemp("own")
    run = simulate(car, car.truth("track"), duration_s=3.0, rate_hz=200.0, seed=3).run
    log = write_log(frames_from_run(run), d / "run.log")
    return run, log, {s: convert(log, d / f"run{s}") for s in FORMATS}


@pytest.fixture(scope="module")
def rav4_logs(tmp_path_factory, rav4_paths):
    d = tmp_path_factory.mktemp("rav4")
    log, dbc = rav4_paths
    short = write_log(itertools.islice(can.LogReader(str(log)), RAV4_FRAMES), d / "rav4.log")
    return short, dbc, {s: convert(short, d / f"rav4{s}") for s in FORMATS}


@pytest.mark.parametrize("suffix", FORMATS)
def test_own_frames_in_every_format_give_the_samples_and_estimate_of_the_log(own_logs, car, suffix):
    run, log, converted = own_logs
    ref, _ = samples_of(log)
    got, _ = samples_of(converted[suffix])
    assert len(ref) == len(run)
    assert_same_samples(ref, got, time_tol=1e-9)  # the sample time is SAMPLE_TIME, in every format
    a, b = estimate(ref, car), estimate(got, car)
    np.testing.assert_allclose(b.parameters.to_vector(), a.parameters.to_vector(), rtol=1e-9)


@pytest.mark.parametrize("suffix", FORMATS)
def test_rav4_log_in_every_format_gives_the_samples_and_estimate_of_the_log(rav4_logs, suffix):
    log, dbc, converted = rav4_logs
    kw = {"dbc": dbc, "signals": "toyota_rav4_2017"}
    ref, ref_src = samples_of(log, **kw)
    got, src = samples_of(converted[suffix], **kw)
    assert len(ref) > 200  # KINEMATICS at 83 Hz
    assert_same_samples(ref, got, time_tol=2e-6)  # .mf4 keeps bus times as float32 offsets
    if suffix in (".csv", ".db"):  # python-can's CSV and SQLite keep no channel: both buses pass
        assert set(src.report()["channels_seen"]) == {"None"}
    else:  # 0 in .asc/.blf/.mf4, 1 in .trc, 'can0' in .log: all can0 here
        assert src.report()["channels_seen"] == ref_src.report()["channels_seen"]
        assert set(src.report()["channels_seen"]) == {"can0", "can1"}
        assert src.report()["other_channel"] == ref_src.report()["other_channel"] > 0
    rav4 = load_vehicle("rav4_2017")
    a, b = estimate(ref, rav4), estimate(got, rav4)
    # .mf4's float32 time offsets (2e-6 s) move the cubic's slopes, which take the samples' times: 5e-6 measured
    np.testing.assert_allclose(b.parameters.to_vector(), a.parameters.to_vector(),
                               rtol=2e-5 if suffix == ".mf4" else 1e-6)


def test_channel_names_are_the_same_in_every_format():
    assert normalise_channel("can0", ".log") == normalise_channel(0, ".asc") == normalise_channel(0, ".blf") \
        == normalise_channel(0, ".mf4") == normalise_channel(1, ".trc") == normalise_channel("vcan0") == "can0"
    assert normalise_channel(2, ".trc") == normalise_channel("can1") == normalise_channel("1") == "can1"
    assert normalise_channel(None, ".csv") is None
    assert normalise_channel("chassis") == "chassis"


def test_can_channel_selects_a_bus_and_a_wrong_one_lists_the_channels_seen(rav4_logs, capsys):
    log, dbc, converted = rav4_logs
    base = ["--dbc", str(dbc), "--signals", "toyota_rav4_2017", "--vehicle", "rav4_2017"]
    # .trc numbers channels from 1: its channel 1 is can0, the map's channel
    assert main(["estimate", str(converted[".trc"]), *base, "--can-channel", "0"]) == 0
    assert "EKF over" in capsys.readouterr().out
    assert main(["estimate", str(converted[".trc"]), *base, "--can-channel", "can7"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "--can-channel can7 matches no frame; the log has can0 (" in err
    assert "can1 (" in err
    # a channel with frames, but the map's messages all on another: the channel is the cause, not the DBC
    assert main(["estimate", str(converted[".asc"]), *base, "--can-channel", "can1"]) == 2
    err = capsys.readouterr().err.strip()
    assert "--can-channel can1 has 2,285 frames but none of the map's messages (KINEMATICS" in err
    assert err.endswith("they are on can0 (628 frames): --can-channel can0") and "wrong DBC" not in err


def test_a_can_log_without_a_usable_sample_exits_2_with_the_reason(tmp_path, own_logs, rav4_logs, capsys):
    run, log, _ = own_logs
    rav4, dbc, _ = rav4_logs
    empty = tmp_path / "empty.log"
    empty.write_text("")
    no_trigger = write_log([m for m in can.LogReader(str(log)) if m.arbitration_id != 0x104], tmp_path / "nt.blf")
    cases = [
        ([str(empty)], "the log holds no frame"),
        ([str(no_trigger)], "no trigger frame OID_SPEED_TIME"),
        ([str(log), "--signals", "toyota_rav4_2017", "--dbc", str(dbc)], "no frame with an ID the map"),
        ([str(rav4)], "no frame with an ID the map online_id uses"),  # a car's log without its DBC
    ]
    for argv, reason in cases:
        assert main(["estimate", *argv]) == 2, argv
        err = capsys.readouterr().err.strip()
        assert err.startswith("online-id: error: ") and argv[0] in err and reason in err, err
        assert err.count("\n") == 0


def test_unreadable_logs_are_one_line_naming_the_file(tmp_path, own_logs, capsys):
    _, _, converted = own_logs
    data = bytearray(converted[".blf"].read_bytes())
    data[200:400] = bytes(range(200))  # garble the first object
    corrupt = tmp_path / "corrupt.blf"
    corrupt.write_bytes(bytes(data))
    garbage = tmp_path / "garbage.mf4"
    garbage.write_bytes(b"MDF     4.10    " + bytes(300))
    truncated = tmp_path / "truncated.asc"
    text = converted[".asc"].read_text()
    truncated.write_text(text[: len(text) // 2] + "\n   1.0 1 12Z Rx d 8 zz\n")
    for path in (corrupt, garbage, truncated):
        code = main(["estimate", str(path)])
        err = capsys.readouterr().err.strip()
        assert code == 2 and err.count("\n") == 0 and str(path) in err, (path, err)


def test_channels_changes_the_result_on_a_can_log_as_on_the_csv(tmp_path, own_logs, capsys):
    run, log, _ = own_logs
    csv = write_track_run(run, tmp_path / "run.csv")
    out = {}
    for name, argv in {"can_all": [str(log)], "can_yaw": [str(log), "--channels", "yaw_rate"],
                       "csv_yaw": [str(csv), "--channels", "yaw_rate"]}.items():
        assert main(["estimate", *argv, "--quiet", "--no-polish", "--json", str(tmp_path / f"{name}.json")]) == 0
        out[name] = json.loads((tmp_path / f"{name}.json").read_text())
    vec = {k: np.array([v["parameters"][n]["value"] for n in v["parameters"]]) for k, v in out.items()}
    assert out["can_yaw"]["channels"] == ["yaw_rate"]
    assert np.max(np.abs(vec["can_yaw"] / vec["can_all"] - 1)) > 1e-3  # the roll channels were really left out
    np.testing.assert_allclose(vec["can_yaw"], vec["csv_yaw"], rtol=1e-3)  # and it is the CSV's estimate


def test_an_mf4_of_decoded_signals_is_read_by_name_with_units_converted(tmp_path, car):
    from asammdf import MDF, Signal

    run = simulate(car, car.truth("track"), duration_s=2.0, rate_hz=200.0, seed=5).run
    t = run.time
    slow = slice(None, None, 2)  # speed logged at half the rate: the latest value is used
    signals = [
        Signal(np.rad2deg(run.steering_wheel_angle), t, name="steering_wheel_angle", unit="deg"),
        Signal(run.speed[slow] * 3.6, t[slow], name="speed", unit="km/h"),
        Signal(run.yaw_rate, t, name="yaw_rate", unit="rad/s"),
        Signal(run.lateral_acceleration, t, name="lateral_acceleration", unit="m/s^2"),
        Signal(run.roll_angle, t, name="roll_angle", unit="rad"),
    ]
    mdf = MDF()
    mdf.append(signals)
    path = tmp_path / "logger.mf4"
    mdf.save(str(path), overwrite=True)
    got, src = samples_of(path)
    assert len(got) == len(run)
    np.testing.assert_allclose([s.steering_wheel_angle for s in got], run.steering_wheel_angle, atol=1e-12)
    np.testing.assert_allclose([s.yaw_rate for s in got], run.yaw_rate, atol=1e-12)
    expected_speed = run.speed[(np.arange(len(run)) // 2) * 2]
    np.testing.assert_allclose([s.speed for s in got], expected_speed, rtol=1e-12)
    assert src.channels == ["yaw_rate", "roll_angle", "lateral_acceleration"]
    assert all(s.roll_rate is None for s in got)
    # a unit that does not fit the column is an error naming the channel
    mdf = MDF()
    mdf.append([Signal(run.steering_wheel_angle, t, name="steering_wheel_angle", unit="rad"),
                Signal(run.speed, t, name="speed", unit="m/s"), Signal(run.yaw_rate, t, name="yaw_rate", unit="km/h")])
    bad = tmp_path / "bad.mf4"
    mdf.save(str(bad), overwrite=True)
    with pytest.raises(OnlineIdError, match=r"bad.mf4: channel 'yaw_rate': unit 'km/h'"):
        open_source(bad)


def test_an_mf4_of_dbc_signals_is_read_through_the_signal_map(tmp_path, rav4_logs):
    from asammdf import MDF, Signal

    log, dbc, _ = rav4_logs
    ref, _ = samples_of(log, dbc=dbc, signals="toyota_rav4_2017")
    # what a logger decoding the bus with the DBC records: DBC units, MESSAGE.SIGNAL names
    t = np.array([s.time for s in ref]) - ref[0].time
    deg = np.rad2deg
    signals = [Signal(deg([s.yaw_rate for s in ref]), t, name="KINEMATICS.YAW_RATE", unit="deg/s"),
               Signal(-np.array([s.lateral_acceleration for s in ref]), t, name="KINEMATICS.ACCEL_Y", unit="m/s^2"),
               Signal(np.array([s.speed for s in ref]) * 3.6, t, name="SPEED.SPEED", unit="km/h")]
    mdf = MDF()
    mdf.append(signals)
    path = tmp_path / "decoded.mf4"
    mdf.save(str(path), overwrite=True)
    # the steering angle is a sum of two DBC signals: no single channel; the map says so
    with pytest.raises(OnlineIdError, match="no channel for steering_wheel_angle"):
        open_source(path, signals="toyota_rav4_2017")
    mdf.append([Signal(deg([s.steering_wheel_angle for s in ref]), t, name="steering_wheel_angle", unit="deg")])
    mdf.save(str(path), overwrite=True)
    got, src = samples_of(path, signals="toyota_rav4_2017")
    assert len(got) == len(ref) and src.trigger == "yaw_rate"  # KINEMATICS completes a sample, as on the bus
    np.testing.assert_allclose([s.yaw_rate for s in got], [s.yaw_rate for s in ref], rtol=1e-12)
    np.testing.assert_allclose([s.lateral_acceleration for s in got], [s.lateral_acceleration for s in ref])


def test_a_mapped_channel_whose_frames_never_come_is_not_claimed_as_used(tmp_path, car, capsys):
    run = simulate(car, car.truth("track"), duration_s=1.0, rate_hz=200.0, seed=6).run
    run.roll_angle = run.roll_rate = None  # a car without a roll sensor: no OID_ROLL frames
    log = write_log(frames_from_run(run), tmp_path / "noroll.log")
    assert main(["estimate", str(log), "--quiet", "--json", str(tmp_path / "e.json")]) == 0
    assert json.loads((tmp_path / "e.json").read_text())["channels"] == ["yaw_rate", "lateral_acceleration"]
    assert "roll_angle, roll_rate mapped but in no sample: not used" in capsys.readouterr().err
