"""The track-run CSV: round trip, and a clear message for every kind of bad input."""

from __future__ import annotations

import numpy as np
import pytest

from online_id.errors import LogFormatError
from online_id.io.tracklog import read_track_run, write_track_run
from online_id.sim.simulator import simulate
from online_id.vehicle import load_vehicle

HEADER = "time,steering_wheel_angle,speed,yaw_rate,lateral_acceleration,roll_angle\n"


def _rows(n=20, dt=0.01):
    return [[i * dt, 0.01 * i, 22.0, 0.001 * i, 0.1, 0.0005] for i in range(n)]


def _write(tmp_path, rows, header=HEADER, name="run.csv"):
    p = tmp_path / name
    p.write_text(header + "".join(",".join(str(c) for c in r) + "\n" for r in rows))
    return p


def test_round_trip_keeps_values_channels_and_truth(tmp_path):
    car = load_vehicle("haro2008")
    sim = simulate(car, car.truth("track"), duration_s=2.0, rate_hz=500.0)
    path = write_track_run(sim.run, tmp_path / "run.csv")
    back = read_track_run(path)
    assert back.channels == sim.run.channels
    for c in back.channels:
        np.testing.assert_allclose(getattr(back, c), getattr(sim.run, c), rtol=1e-9, atol=1e-12)
    assert back.truth == car.truth("track").to_dict()
    assert back.sampling.rate_hz == pytest.approx(500.0)
    assert back.sampling.gaps == () and not back.sampling.uneven


def test_optional_columns_may_be_absent_and_extra_columns_are_ignored(tmp_path):
    rows = [r[:5] + [7.0] for r in _rows()]
    p = _write(tmp_path, rows, header="time,steering_wheel_angle,speed,yaw_rate,lateral_acceleration,brake\n")
    run = read_track_run(p)
    assert run.roll_angle is None and run.channels[-1] == "lateral_acceleration"


def _fails(tmp_path, rows, needle, header=HEADER):
    p = _write(tmp_path, rows, header)
    with pytest.raises(LogFormatError) as info:
        read_track_run(p)
    msg = str(info.value)
    assert str(p) in msg, msg
    for part in needle if isinstance(needle, tuple) else (needle,):
        assert part in msg, msg
    assert "\n" not in msg
    return msg


def test_missing_required_column(tmp_path):
    _fails(tmp_path, [r[:4] for r in _rows()], ("line 1", "missing required column(s) lateral_acceleration"),
           header="time,steering_wheel_angle,speed,yaw_rate\n")


def test_non_numeric_cell(tmp_path):
    rows = _rows()
    rows[5][3] = "abc"
    _fails(tmp_path, rows, ("line 7", "column 'yaw_rate'", "'abc' is not a number"))


def test_empty_cell(tmp_path):
    rows = _rows()
    rows[3][5] = ""
    _fails(tmp_path, rows, ("line 5", "column 'roll_angle'", "empty cell"))


@pytest.mark.parametrize("bad", ["nan", "NaN", "inf", "-inf"])
def test_nan_and_inf(tmp_path, bad):
    rows = _rows()
    rows[8][4] = bad
    _fails(tmp_path, rows, ("line 10", "column 'lateral_acceleration'", "NaN or inf"))


def test_time_going_backwards(tmp_path):
    rows = _rows()
    rows[10][0] = 0.05
    _fails(tmp_path, rows, ("line 12", "column 'time'", "goes backwards"))


def test_time_repeating(tmp_path):
    rows = _rows()
    rows[10][0] = rows[9][0]
    _fails(tmp_path, rows, ("line 12", "time repeats"))


@pytest.mark.parametrize("col,value,hint", [
    (1, 90.0, "degrees instead of radians"),
    (3, 25.0, "deg/s instead of rad/s"),
    (2, 130.0, "km/h instead of m/s"),
])
def test_values_whose_size_says_the_unit_is_wrong(tmp_path, col, value, hint):
    rows = _rows()
    rows[4][col] = value
    _fails(tmp_path, rows, ("line 6", hint))


def test_truncated_last_row(tmp_path):
    rows = _rows()
    rows[-1] = rows[-1][:2]
    _fails(tmp_path, rows, ("line 21", "truncated"))


def test_empty_file_and_header_only(tmp_path):
    p = tmp_path / "empty.csv"
    p.write_text("")
    with pytest.raises(LogFormatError, match="empty file"):
        read_track_run(p)
    _fails(tmp_path, [], "0 data row(s)")


def test_missing_file(tmp_path):
    with pytest.raises(LogFormatError, match="no such file"):
        read_track_run(tmp_path / "nope.csv")


def test_gaps_and_uneven_sampling_are_reported_not_fatal(tmp_path):
    rows = _rows(50)
    for r in rows[30:]:
        r[0] += 0.5  # a 0.5 s dropout after row 30
    rows[10][0] += 0.003  # jitter
    run = read_track_run(_write(tmp_path, rows))
    rep = run.sampling
    assert len(rep.gaps) == 1 and rep.gaps[0][0] == pytest.approx(0.29) and rep.gaps[0][1] == pytest.approx(0.51)
    assert rep.uneven
    text = " ".join(rep.warnings())
    assert "gap" in text and "0.51 s at t = 0.290 s" in text and "uneven" in text
