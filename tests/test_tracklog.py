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


# -- the fast reader, and files written by spreadsheets ---------------------------------------------------
from online_id.io.tracklog import read_track_run_rowwise  # noqa: E402


def test_fast_reader_gives_the_rowwise_readers_numbers(tmp_path):
    car = load_vehicle("haro2008")
    sim = simulate(car, car.truth("track"), duration_s=2.0, rate_hz=500.0)
    path = write_track_run(sim.run, tmp_path / "run.csv")
    fast, slow = read_track_run(path), read_track_run_rowwise(path)
    assert fast.channels == slow.channels
    for c in fast.channels:
        np.testing.assert_array_equal(getattr(fast, c), getattr(slow, c))
    assert fast.meta == slow.meta


def test_a_utf8_byte_order_mark_is_skipped(tmp_path):
    plain = _write(tmp_path, _rows(), name="plain.csv")
    bom = tmp_path / "bom.csv"
    bom.write_bytes(b"\xef\xbb\xbf" + plain.read_bytes())
    for reader in (read_track_run, read_track_run_rowwise):
        run = reader(bom)
        assert run.channels == read_track_run(plain).channels
        np.testing.assert_array_equal(run.time, read_track_run(plain).time)


def test_a_utf16_file_is_named_as_such(tmp_path):
    p = tmp_path / "u16.csv"
    p.write_bytes((HEADER + "0,0,22,0,0,0\n").encode("utf-16"))
    with pytest.raises(LogFormatError, match="UTF-16.*save it as UTF-8"):
        read_track_run(p)


@pytest.mark.parametrize("sep,what", [(";", "semicolons"), ("\t", "tabs")])
def test_other_separators_are_named_not_listed_as_missing_columns(tmp_path, sep, what):
    p = tmp_path / "run.csv"
    p.write_text(HEADER.replace(",", sep) + "".join(sep.join(str(c) for c in r) + "\n" for r in _rows()))
    for reader in (read_track_run, read_track_run_rowwise):
        with pytest.raises(LogFormatError) as info:
            reader(p)
        msg = str(info.value)
        assert str(p) in msg and "line 1" in msg and f"separated by {what};" in msg, msg
        assert "missing" not in msg and "decimal commas" not in msg


def test_semicolons_with_decimal_commas_are_named(tmp_path):
    p = tmp_path / "run.csv"
    p.write_text(HEADER.replace(",", ";") + "".join(";".join(str(c).replace(".", ",") for c in r) + "\n"
                                                    for r in _rows()))
    with pytest.raises(LogFormatError, match="separated by semicolons and decimal commas"):
        read_track_run(p)


def test_decimal_commas_in_a_comma_separated_file(tmp_path):
    rows = _rows()
    text = HEADER + "".join(",".join(str(c) for c in r) + "\n" for r in rows[:3])
    text += "0,03,0,03,22,0,0,003,0,1,0,0005\n"  # a row written with decimal commas
    p = tmp_path / "run.csv"
    p.write_text(text + "".join(",".join(str(c) for c in r) + "\n" for r in rows[4:]))
    for reader in (read_track_run, read_track_run_rowwise):
        with pytest.raises(LogFormatError) as info:
            reader(p)
        msg = str(info.value)
        assert "line 5" in msg and "12 cells, header has 6" in msg and "decimal commas?" in msg, msg


def test_an_empty_trailing_cell_is_still_accepted(tmp_path):
    p = tmp_path / "run.csv"
    p.write_text(HEADER + "".join(",".join(str(c) for c in r) + ",\n" for r in _rows()))
    assert len(read_track_run(p)) == 20


def test_blank_lines_and_quoted_numbers_take_the_careful_path_and_still_read(tmp_path):
    p = tmp_path / "run.csv"
    rows = _rows()
    p.write_text(HEADER + "\n".join(",".join(f'"{c}"' for c in r) for r in rows[:5]) + "\n\n"
                 + "".join(",".join(str(c) for c in r) + "\n" for r in rows[5:]))
    run = read_track_run(p)
    assert len(run) == 20
    np.testing.assert_allclose(run.yaw_rate, [r[3] for r in rows])


def test_a_bad_cell_is_named_after_the_fast_parse_fails(tmp_path):
    rows = _rows(2000)
    rows[1500][2] = "22.O"
    _fails(tmp_path, rows, ("line 1502", "column 'speed'", "'22.O' is not a number"))


# -- files whose lines are not lines (issue 30) -------------------------------------------------------------
HEADER_5 = "time,steering_wheel_angle,speed,yaw_rate,lateral_acceleration\n"


def _row(i: int) -> str:
    return f"{0.01 * i:.2f},0.01,20.0,0.001,0.02"


@pytest.mark.parametrize("content, line", [
    (HEADER_5 + ",".join(_row(i) for i in range(200)), 2),  # the rows' line breaks lost
    ("x" * 5000 + HEADER_5, 1),  # a header line beyond the bound
    (HEADER_5 + "\n".join(_row(i) for i in range(5)) + "\n" + "1," * 3000 + "\n", 7),  # one long row, later on
])
def test_a_line_beyond_the_bound_is_refused_naming_the_missing_line_breaks(tmp_path, content, line):
    path = tmp_path / "run.csv"
    path.write_text(content)
    for reader in (read_track_run, read_track_run_rowwise):
        with pytest.raises(LogFormatError, match=rf"line {line}: longer than 1,000 bytes without a line break"):
            reader(path, max_line_bytes=1000)


def test_nul_bytes_are_a_binary_file_not_a_csv(tmp_path):
    path = tmp_path / "run.csv"
    path.write_bytes((HEADER_5 + _row(0) + "\n" + _row(1) + "\n").encode() + b"\0\0\0" + b"\n" * 10)
    with pytest.raises(LogFormatError, match=r"NUL byte at byte 1\d\d: a binary file"):
        read_track_run(path)


def test_a_file_of_one_line_under_the_bound_says_its_rows_are_on_the_header_line(tmp_path):
    path = tmp_path / "run.csv"
    path.write_text(HEADER_5.strip() + "," + ",".join(_row(i) for i in range(50)))
    with pytest.raises(LogFormatError, match="holds 250 numbers after the column names.*line breaks are missing"):
        read_track_run(path)


def test_realistic_sizes_are_refused_at_the_first_megabyte(tmp_path):
    """150 MB of one line (was 29-48 s and 2-7 GB before a misleading 'decimal comma?' hint) and 200 MB of
    NUL bytes (0.8 GB): refused having read about one MiB; memory traced in Python stays under 8 MB."""
    import tracemalloc

    one_line = tmp_path / "one_line.csv"
    chunk = ",".join(_row(i) for i in range(50_000)).encode() + b","
    with one_line.open("wb") as fh:
        fh.write(HEADER_5.encode())
        for _ in range(150_000_000 // len(chunk) + 1):
            fh.write(chunk)
    nul = tmp_path / "nul.csv"
    with nul.open("wb") as fh:
        fh.truncate(200_000_000)  # sparse: 200 MB of NUL bytes
    for path, message in ((one_line, "line 2: longer than"), (nul, "NUL byte at byte 0")):
        tracemalloc.start()
        try:
            with pytest.raises(LogFormatError, match=message):
                read_track_run(path)
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
        assert peak < 8e6, (path.name, peak)
