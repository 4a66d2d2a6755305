"""Property-based: any track-run table or CAN log, however broken, ends in a result or one clear error line,
never a traceback or an internal error; every JSON written is strict JSON (issue 29 item 4).

Generated track-run tables: any column order, extra and missing columns, finite values of any size,
NaN/inf bursts, text and empty cells, repeated, unsorted, jittered or millisecond times, 2 rows up. Generated
CAN logs (candump text, the RAV4 DBC and map): the map's frames with encoded or random payloads, unknown IDs,
wrong DLC, other channels, non-increasing times, a DBC with a wrong scale. Each goes through ``estimate``,
``fit``, ``check``, ``decode`` in-process (``online_id.cli.main.main``) and through the Python API.

The examples are derandomised (the same ones every run) and bounded for the suite's time. A longer campaign:
``HYPOTHESIS_PROFILE=long`` (or ``HYPOTHESIS_MAX_EXAMPLES=N``) raises the examples and draws new ones.
"""

from __future__ import annotations

import json
import os
import re
import warnings
from pathlib import Path

import numpy as np
import pytest

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402
from hypothesis.control import currently_in_test_context  # noqa: E402

from online_id.cli.main import main  # noqa: E402
from online_id.errors import OnlineIdError  # noqa: E402
from tests.conftest import RAV4_DBC  # noqa: E402

_COMMON = dict(deadline=None, print_blob=True,
               suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                      HealthCheck.function_scoped_fixture])
settings.register_profile("ci", derandomize=True, database=None, **_COMMON)
settings.register_profile("long", derandomize=False, database=None, **_COMMON)
PROFILE = os.environ.get("HYPOTHESIS_PROFILE", "ci")
#: The examples each test runs in CI (fixed seed), as a multiple: ``HYPOTHESIS_MAX_EXAMPLES`` sets the base.
BASE_EXAMPLES = int(os.environ.get("HYPOTHESIS_MAX_EXAMPLES", 1000 if PROFILE == "long" else 6))


def examples(factor: float):
    return settings(settings.get_profile(PROFILE), max_examples=max(1, int(BASE_EXAMPLES * factor)))


# -- what every outcome must be --------------------------------------------------------------------------

def _refuse_constant(text):
    raise ValueError(f"not strict JSON: {text}")


def _strict_json(path: Path) -> dict:
    return json.loads(path.read_text(encoding="utf-8"), parse_constant=_refuse_constant)


def _ends_cleanly(rc: int, err: str, outputs: list[Path]) -> None:
    """A result (0) or one clear error line (2); no traceback, no internal error; written JSON is strict."""
    assert "Traceback" not in err, err
    assert "internal error" not in err, err
    assert rc in (0, 2), (rc, err)
    if rc == 2:
        errors = [line for line in err.splitlines() if line.startswith("online-id: error: ")]
        assert len(errors) == 1, err
    for path in outputs:
        if path.suffix == ".json" and path.exists():
            _strict_json(path)


def _kind_of_error(err: str) -> str:
    """The first words of the error line, the file name left out (for the statistics of a campaign)."""
    line = next(line for line in err.splitlines() if line.startswith("online-id: error: "))
    words = line.removeprefix("online-id: error: ").split(": ")
    words = words[1:] if len(words) > 1 and ("/" in words[0] or words[0].endswith((".csv", ".log"))) else words
    return re.sub(r"[-+]?\d[\d.,e+-]*", "#", ": ".join(words))[:60]


def _run(capsys, argv: list[str], outputs: list[Path]) -> int:
    for p in outputs:
        p.unlink(missing_ok=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rc = main(argv)
    err = capsys.readouterr().err
    _ends_cleanly(rc, err, outputs)
    if currently_in_test_context():  # the statistics of a campaign (--hypothesis-show-statistics)
        hypothesis.event(f"{argv[0]}: exit {rc}" + (f" ({_kind_of_error(err)})" if rc else ""))
    _run.last_error = err
    if rc == 0:
        for p in outputs:
            assert p.exists(), (argv, p)
    return rc


# -- track-run tables --------------------------------------------------------------------------------------

COLUMNS = ("time", "steering_wheel_angle", "speed", "yaw_rate", "lateral_acceleration", "roll_angle", "roll_rate",
           "lateral_velocity")
EXTRA_COLUMNS = ("longitudinal_acceleration", "Unnamed: 0", "yaw_rate_deg", "comment", "TIME", " speed")
#: A typical size of each channel [SI], for signals that look like a car's.
TYPICAL = {"steering_wheel_angle": 0.4, "speed": 22.0, "yaw_rate": 0.2, "lateral_acceleration": 4.0,
           "roll_angle": 0.03, "roll_rate": 0.2, "lateral_velocity": 0.5}
SPECIAL = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.sampled_from([0.0, -0.0, 1e308, -1e308,
                                                                                      5e-324, 1e-12, 1e12]))


#: What can be wrong with a table: each example takes none (a car's run) to a few of these.
DEFECTS = ("missing column", "extra column", "constant", "noise", "huge", "scaled", "reversed", "swapped",
           "special burst", "text cell", "empty cell", "jittered time", "repeated time", "unsorted time",
           "gaps", "milliseconds", "random time", "shifted start")


@st.composite
def track_tables(draw) -> dict:
    """{column: list of cell texts}, the column order and the row count: a car-like track run (a chirp of a
    random frequency and size at a random speed, with noise) with up to four defects of :data:`DEFECTS`."""
    n = draw(st.one_of(st.integers(13, 400), st.integers(2, 12), st.integers(900, 1600)))  # the first is the simplest
    rate = draw(st.sampled_from([1000.0, 200.0, 100.0, 50.0, 10.0]))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    t = np.arange(n) / rate
    f0, amplitude = rng.uniform(0.05, 1.0), rng.uniform(0.0, 1.0)
    steer = amplitude * TYPICAL["steering_wheel_angle"] * np.sin(2 * np.pi * (f0 + 0.1 * t) * t)
    speed = np.full(n, TYPICAL["speed"] * rng.uniform(0.1, 2.0)) + rng.normal(0, 0.05, n)
    gain = speed / (2.5 * 16.0)  # a steady-state yaw-rate gain of a car of 2.5 m
    cols = {"time": t, "steering_wheel_angle": steer, "speed": speed, "yaw_rate": steer * gain,
            "lateral_acceleration": steer * gain * speed, "roll_angle": 0.005 * steer * gain * speed,
            "roll_rate": np.gradient(0.005 * steer * gain * speed, t) if n > 1 else np.zeros(n),
            "lateral_velocity": 0.1 * steer * speed}
    for c in cols:
        if c != "time":
            cols[c] = cols[c] + rng.normal(0, 0.01 * TYPICAL[c], n)
    for defect in draw(st.lists(st.sampled_from(DEFECTS), max_size=4)):
        c = draw(st.sampled_from(sorted(cols)))
        if c not in cols:
            continue
        v = cols[c]
        if defect == "missing column":
            del cols[c]
        elif defect == "extra column":
            cols[draw(st.sampled_from(EXTRA_COLUMNS))] = rng.normal(0, 1, n)
        elif defect == "constant":
            cols[c] = np.full(n, draw(st.sampled_from([0.0, 1.0, -0.3])))
        elif defect == "noise":
            cols[c] = rng.normal(np.mean(v), np.std(v) + 1e-3, n)
        elif defect == "huge":
            cols[c] = v * 10.0 ** draw(st.integers(3, 300))
        elif defect == "scaled":
            cols[c] = v * draw(st.sampled_from([57.3, 3.6, 1 / 9.81, -1.0, 1e-3]))
        elif defect == "reversed":
            cols[c] = v[::-1].copy()
        elif defect == "swapped":
            other = draw(st.sampled_from(sorted(cols)))
            cols[c], cols[other] = cols[other], v
        elif defect in ("jittered time", "repeated time", "unsorted time", "gaps", "milliseconds", "random time",
                        "shifted start") and "time" in cols:
            t = cols["time"]
            if defect == "jittered time":
                t = t + rng.uniform(-0.45, 0.45, n) / rate
            elif defect == "repeated time":
                t = t.copy()
                t[rng.integers(1, n) if n > 1 else 0] = t[rng.integers(0, n)]
            elif defect == "unsorted time":
                t = rng.permutation(t)
            elif defect == "gaps":
                t = t + np.cumsum(rng.random(n) < 0.05) * rng.uniform(0.05, 2.0)
            elif defect == "milliseconds":
                t = t * 1000.0
            elif defect == "random time":
                t = np.sort(rng.uniform(-1e3, 1e3, n))
            else:
                t = t + draw(st.sampled_from([3.5, 46408.58, -20.0, 1e9]))
            cols["time"] = t
    cells = {c: [f"{x:.10g}" for x in v] for c, v in cols.items()}
    for defect in ("special burst", "text cell", "empty cell"):
        if not (cells and draw(st.integers(0, 5)) == 5):  # one in six (0, hypothesis's simplest, is no defect)
            continue
        c = draw(st.sampled_from(sorted(cells)))
        start, length = draw(st.integers(0, n - 1)), draw(st.integers(1, 20))
        value = {"special burst": draw(SPECIAL.map(repr)), "text cell": draw(st.sampled_from(["abc", "1,5", "--"])),
                 "empty cell": draw(st.sampled_from(["", " "]))}[defect]
        for i in range(start, min(n, start + length)):
            cells[c][i] = value
    order = draw(st.permutations(sorted(cells)))
    return {"order": list(order), "cells": cells, "n": n}


def _write_table(table: dict, path: Path) -> Path:
    order, cells = table["order"], table["cells"]
    lines = [",".join(order)] + [",".join(cells[c][i] for c in order) for i in range(table["n"])]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


@examples(4)
@given(table=track_tables(), polish=st.booleans(), filter_=st.sampled_from(["ekf", "ukf"]))
def test_estimate_of_any_table_ends_in_a_result_or_one_line(table, polish, filter_, tmp_path_factory, capsys):
    folder = tmp_path_factory.mktemp("estimate")
    log = _write_table(table, folder / "run.csv")
    out, trace = folder / "est.json", folder / "trace.csv"
    _run(capsys, ["estimate", str(log), "--quiet", "--filter", filter_, "--polish" if polish else "--no-polish",
                  "--json", str(out), "--trace", str(trace)], [out, trace])


@examples(1.5)
@given(table=track_tables())
def test_fit_of_any_table_ends_in_a_result_or_one_line(table, tmp_path_factory, capsys):
    folder = tmp_path_factory.mktemp("fit")
    log = _write_table(table, folder / "run.csv")
    out = folder / "fit.json"
    _run(capsys, ["fit", str(log), "--quiet", "--generations", "1", "--groups", "1", "--json", str(out)], [out])


@examples(3)
@given(table=track_tables())
def test_check_of_any_table_ends_in_a_result_or_one_line(table, tmp_path_factory, capsys):
    folder = tmp_path_factory.mktemp("check")
    log = _write_table(table, folder / "run.csv")
    out = folder / "check.json"
    _run(capsys, ["check", str(log), "--json", str(out)], [out])


@examples(2)
@given(table=track_tables())
def test_the_api_on_any_table_gives_a_result_or_an_online_id_error(table, tmp_path_factory):
    """The Python API: a result, whose JSON is strict, or an OnlineIdError; nothing else."""
    import online_id

    pd = pytest.importorskip("pandas")
    folder = tmp_path_factory.mktemp("api")
    log = _write_table(table, folder / "run.csv")
    frame = None
    try:
        frame = pd.read_csv(log)
    except Exception:  # noqa: BLE001 - pandas refusing the table is not online-id's business
        pass
    sources = [log] + ([frame] if frame is not None else [])
    for source in sources:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                est = online_id.estimate(source)
            except OnlineIdError as exc:
                assert str(exc) and "\n" not in str(exc)
            else:
                json.loads(est.to_json(), parse_constant=_refuse_constant)
                assert set(est.parameters) == {"Mzz", "Mxx", "D1", "D2", "Aro", "Kro", "b1", "b2"}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            fit = online_id.fit(log, generations=1, groups=1)
        except OnlineIdError as exc:
            assert str(exc) and "\n" not in str(exc)
        else:
            json.loads(fit.to_json(), parse_constant=_refuse_constant)


# -- CAN logs ----------------------------------------------------------------------------------------------

MAP_MESSAGES = {"KINEMATICS": 0x24, "STEER_ANGLE_SENSOR": 0x25, "SPEED": 0xB4}


def _database(scale_of_yaw: float = 1.0):
    import cantools

    text = RAV4_DBC.read_text(encoding="utf-8")
    if scale_of_yaw != 1.0:  # a DBC with a wrong scale: the yaw rate comes out that many times too large
        text = text.replace("YAW_RATE : 1|10@0+ (0.244,-125)", f"YAW_RATE : 1|10@0+ ({0.244 * scale_of_yaw:g},-125)")
    return cantools.database.load_string(text, database_format="dbc"), text


@st.composite
def can_logs(draw) -> dict:
    """A candump text log over the RAV4 DBC's messages, however broken; and the DBC to read it with."""
    n = draw(st.one_of(st.integers(6, 300), st.integers(0, 5), st.integers(1200, 1600)))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    yaw_scale = draw(st.sampled_from([1.0, 1.0, 1.0, 1000.0, 0.001]))
    db, dbc_text = _database(yaw_scale)
    t0 = draw(st.sampled_from([0.0, 46408.58]))
    dt = draw(st.sampled_from([0.012, 0.012, 0.001, 0.1, 0.5]))
    turning = draw(st.floats(0.0, 20.0))
    speed_kmh = draw(st.sampled_from([0.0, 5.0, 60.0, 80.0, 300.0]))
    payload = draw(st.sampled_from(["encoded", "encoded", "random", "mixed"]))
    channels = draw(st.sampled_from([["can0"], ["can0"], ["can1"], ["can0", "can1"], ["vcan7"]]))
    lines = []
    t = t0
    for k in range(n):
        t += dt * draw(st.sampled_from([1.0, 1.0, 1.0, 0.5, 0.0, -1.0])) if k % 50 == 0 else dt
        phase = 2 * np.pi * 0.3 * k * dt
        values = {
            "SPEED": {"ENCODER": 0, "SPEED": speed_kmh, "CHECKSUM": 0},
            "STEER_ANGLE_SENSOR": {"STEER_ANGLE": turning * np.sin(phase), "STEER_FRACTION": 0.0, "STEER_RATE": 0},
            "KINEMATICS": {"ACCEL_Y": 0.3 * turning * np.sin(phase), "YAW_RATE": 0.5 * turning * np.sin(phase),
                           "ACCEL_X": 0.0},
        }
        for name in ("SPEED", "STEER_ANGLE_SENSOR", "KINEMATICS"):  # the trigger last
            frame_id = MAP_MESSAGES[name]
            if payload == "random" or (payload == "mixed" and rng.random() < 0.02):
                data = bytes(rng.integers(0, 256, 8, dtype=np.uint8))
            else:
                try:
                    data = db.encode_message(name, values[name], strict=False)
                except Exception:  # noqa: BLE001 - a value the signal cannot hold: random bytes instead
                    data = bytes(rng.integers(0, 256, 8, dtype=np.uint8))
            if rng.random() < 0.03:  # wrong DLC
                data = data[: int(rng.integers(0, 8))] if rng.random() < 0.5 else data + b"\x00"
            channel = channels[int(rng.integers(0, len(channels)))]
            lines.append(f"({t:.6f}) {channel} {frame_id:03X}#{data.hex().upper()}")
        if rng.random() < 0.2:  # unknown IDs
            junk = bytes(rng.integers(0, 256, 8, dtype=np.uint8)).hex().upper()
            lines.append(f"({t:.6f}) can0 {int(rng.integers(0, 0x7FF)):03X}#{junk}")
    if draw(st.integers(0, 9)) == 9 and lines:  # a truncated last line
        lines[-1] = lines[-1][: int(rng.integers(1, len(lines[-1])))]
    return {"text": "\n".join(lines) + ("\n" if lines else ""), "dbc": dbc_text,
            "can_channel": draw(st.sampled_from([None, None, "can0", "can1", "any", "can5"]))}


def _write_can(log: dict, folder: Path) -> tuple[Path, Path, list[str]]:
    path = folder / "bus.log"
    path.write_text(log["text"], encoding="utf-8")
    dbc = folder / "car.dbc"
    dbc.write_text(log["dbc"], encoding="utf-8")
    args = ["--dbc", str(dbc), "--signals", "toyota_rav4_2017"]
    if log["can_channel"] is not None:
        args += ["--can-channel", log["can_channel"]]
    return path, dbc, args


@examples(3)
@given(log=can_logs())
def test_decode_of_any_can_log_ends_in_a_table_or_one_line(log, tmp_path_factory, capsys):
    folder = tmp_path_factory.mktemp("decode")
    path, _, args = _write_can(log, folder)
    out = folder / "run.csv"
    if _run(capsys, ["decode", str(path), *args, "--out", str(out)], [out]) == 0:
        from online_id.io.tracklog import read_track_run

        read_track_run(out)  # what decode writes, the reader takes


@examples(2.5)
@given(log=can_logs(), command=st.sampled_from(["estimate", "fit"]))
def test_estimate_and_fit_of_any_can_log_end_in_a_result_or_one_line(log, command, tmp_path_factory, capsys):
    folder = tmp_path_factory.mktemp("can")
    path, _, args = _write_can(log, folder)
    out = folder / "out.json"
    extra = ["--generations", "1", "--groups", "1"] if command == "fit" else []
    _run(capsys, [command, str(path), *args, "--vehicle", "rav4_2017", "--quiet", *extra, "--json", str(out)], [out])


@examples(1)
@given(log=can_logs())
def test_the_api_on_any_can_log_gives_a_result_or_an_online_id_error(log, tmp_path_factory):
    import online_id

    folder = tmp_path_factory.mktemp("canapi")
    path, dbc, _ = _write_can(log, folder)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            est = online_id.estimate(path, vehicle="rav4_2017", dbc=dbc, signals="toyota_rav4_2017",
                                     can_channel=log["can_channel"])
        except OnlineIdError as exc:
            assert str(exc) and "\n" not in str(exc)
        else:
            json.loads(est.to_json(), parse_constant=_refuse_constant)


# -- what the campaigns found (each fixed; kept as plain examples) ---------------------------------------------

def _table_text(rows: list[list[float]], columns=("time", "steering_wheel_angle", "speed", "yaw_rate",
                                                   "lateral_acceleration")) -> str:
    return ",".join(columns) + "\n" + "\n".join(",".join(f"{x:.10g}" for x in r) for r in rows) + "\n"


@pytest.mark.parametrize("argv, rows, words", [
    # fit of a 2-row run: numpy's "zero-size array to reduction operation minimum" from the block simulator
    (["fit", "--quiet", "--generations", "1", "--groups", "1"], [[0, 0.005, 32.1, -0.005, -0.19],
                                                                 [0.001, 0.0035, 32.1, -0.0004, -0.004]],
     "too short for the fit"),
    # check of a car at a standstill: the candidate chirp at a median speed of 0 m/s, a singular model
    (["check"], [[0.001 * k, 0.002 * (-1) ** k, 0.01 + 0.005 * (-1) ** k, 0.002, 3.9 + 0.1 * (-1) ** k]
                 for k in range(13)], None),
])
def test_what_the_campaign_found_in_tables(argv, rows, words, tmp_path, capsys):
    log = tmp_path / "run.csv"
    log.write_text(_table_text(rows), encoding="utf-8")
    out = tmp_path / "out.json"
    rc = _run(capsys, [argv[0], str(log), *argv[1:], "--json", str(out)], [out])
    assert (rc == 2) == (words is not None) and (words is None or words in _run.last_error)


def test_check_json_is_strict_on_a_run_too_short_for_a_noise_floor(tmp_path, capsys):
    """check --json wrote NaN (the noise floor of a 2-sample run): not JSON for a strict reader."""
    log = tmp_path / "run.csv"
    log.write_text(_table_text([[0, 0.005, 32.1, -0.005, -0.19], [0.001, 0.0035, 32.1, -0.0004, -0.004]]))
    out = tmp_path / "check.json"
    assert _run(capsys, ["check", str(log), "--json", str(out)], [out]) == 0
    assert _strict_json(out)["crlb_at_noise_floor"]["noise_floor"]["yaw_rate"] is None


@pytest.mark.parametrize("frames, words", [
    # random payloads decode to a steering angle of 13.8 rad: decode wrote a table the reader refused
    ([("0B4", "0000000000000000"), ("025", "1DF04213B6273B04"), ("024", "0200020002000000")] * 2,
     "decoded steering_wheel_angle = "),
    # triggers a second apart: decode wrote a table the reader took for milliseconds
    ([("0B4", "0000000000000000"), ("025", "0000000000000000"), ("024", "0200020002000000")] * 4,
     "decoded samples are 1 s apart (median): too sparse"),
])
def test_what_the_campaign_found_in_can_logs(frames, words, tmp_path, capsys):
    step = 0.001 if "steering" in words else 1.0
    lines = [f"({46408.0 + step * (i // 3):.6f}) can0 {frame_id}#{data}" for i, (frame_id, data) in enumerate(frames)]
    log = tmp_path / "bus.log"
    log.write_text("\n".join(lines) + "\n")
    out = tmp_path / "run.csv"
    assert _run(capsys, ["decode", str(log), "--dbc", str(RAV4_DBC), "--signals", "toyota_rav4_2017", "--out",
                         str(out)], [out]) == 2
    assert words in _run.last_error
