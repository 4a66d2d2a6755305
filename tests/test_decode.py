"""`online-id decode` and the commands that need a TrackRun (fit, diagnose, plot) on CAN logs."""

from __future__ import annotations

import json

import can
import numpy as np
import pytest
from online_id.drivers.frames import frames_from_run

from online_id.cli.main import main
from online_id.io.tracklog import read_track_run, write_track_run
from online_id.sim.simulator import simulate
from online_id.vehicle import PARAMETER_NAMES, load_vehicle

#: The estimate from a decoded log must match the original CSV's within this (relative; the issue's 0.1 %).
SAME_ESTIMATE = 1e-3
#: ID of online-id's OID_YAW_LAT frame (drivers/data/online_id.dbc).
OID_YAW_LAT = 0x102


def write_frames(messages, path):
    with can.Logger(str(path)) as writer:
        for m in messages:
            writer.on_message_received(m)
    return path


def params(path):
    data = json.loads(path.read_text())
    return np.array([data["parameters"][n]["value"] for n in PARAMETER_NAMES])


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Two 6 s runs at 200 Hz (80 and 60 km/h) as CSV and as a .blf of online-id's frames."""
    car = load_vehicle("haro2008")
    d = tmp_path_factory.mktemp("decode")
    out = []
    for i, speed in enumerate((80 / 3.6, 60 / 3.6)):
        run = simulate(car, car.truth("track"), duration_s=6.0, rate_hz=200.0, speed_mps=speed, seed=10 + i).run
        csv = write_track_run(run, d / f"run{i}.csv")
        blf = write_frames(frames_from_run(run), d / f"run{i}.blf")
        out.append((run, csv, blf))
    return out


def test_decode_of_a_blf_read_back_by_estimate_gives_the_csv_estimate(tmp_path, runs, capsys):
    run, csv, blf = runs[0]
    for suffix in (".csv", ".parquet"):
        out = tmp_path / f"decoded{suffix}"
        assert main(["decode", str(blf), "--signals", "online_id", "--out", str(out)]) == 0
        assert f"{len(run)} of {len(run)} samples" in capsys.readouterr().out
        assert main(["estimate", str(out), "--quiet", "--json", str(tmp_path / f"dec{suffix}.json")]) == 0
    assert main(["estimate", str(csv), "--quiet", "--json", str(tmp_path / "orig.json")]) == 0
    decoded = read_track_run(tmp_path / "decoded.csv")
    assert decoded.channels == run.channels[: len(decoded.channels)] and decoded.roll_angle is not None
    np.testing.assert_allclose(decoded.yaw_rate, run.yaw_rate, atol=1e-6)
    orig = params(tmp_path / "orig.json")
    for suffix in (".csv", ".parquet"):
        np.testing.assert_allclose(params(tmp_path / f"dec{suffix}.json"), orig, rtol=SAME_ESTIMATE)


def test_decode_drops_a_sample_whose_frame_is_missing_instead_of_reusing_an_old_value(tmp_path, runs, capsys):
    run, _, blf = runs[0]
    lost = 300  # sample index whose yaw/lateral frame never arrived
    frames = [m for k, m in enumerate(can.LogReader(str(blf)))
              if not (m.arbitration_id == OID_YAW_LAT and k // 4 == lost)]
    log = write_frames(frames, tmp_path / "lossy.log")
    out = tmp_path / "lossy.csv"
    assert main(["decode", str(log), "--out", str(out)]) == 0
    captured = capsys.readouterr()
    assert f"{len(run) - 1} of {len(run)} samples" in captured.out
    assert "1 sample(s) dropped: yaw_rate stale or missing" in captured.err
    decoded = read_track_run(out)
    kept = np.delete(np.arange(len(run)), lost)
    np.testing.assert_allclose(decoded.time, run.time[kept], atol=1e-6)
    np.testing.assert_allclose(decoded.yaw_rate, run.yaw_rate[kept], atol=1e-6)  # no value from sample 299


def test_decode_refuses_what_it_cannot_write_or_read(tmp_path, runs, capsys):
    _, csv, blf = runs[0]
    assert main(["decode", str(blf), "--out", str(tmp_path / "x.txt")]) == 2
    assert main(["decode", str(tmp_path / "none.blf"), "--out", str(tmp_path / "x.csv")]) == 2
    err = capsys.readouterr().err
    assert "write .csv or .parquet" in err and "none.blf: no such file" in err


def test_fit_diagnose_and_plot_accept_a_can_log(tmp_path, runs, capsys):
    (run, csv, blf), (_, _, blf2) = runs
    fit_args = ["--signals", "online_id", "--generations", "3", "--groups", "2", "--quiet"]
    assert main(["fit", str(blf), *fit_args, "--json", str(tmp_path / "fit_can.json")]) == 0
    assert main(["fit", str(csv), *fit_args[2:], "--json", str(tmp_path / "fit_csv.json")]) == 0
    np.testing.assert_allclose(params(tmp_path / "fit_can.json"), params(tmp_path / "fit_csv.json"), rtol=1e-3)
    assert main(["diagnose", str(blf), "--signals", "online_id", "--validate", str(blf2), "--effects",
                 "sensor_bias", "--quiet", "--json", str(tmp_path / "d.json")]) == 0
    d = json.loads((tmp_path / "d.json").read_text())
    assert d["held_out"].startswith("validation run") and d["effects"][0]["name"] == "sensor_bias"
    assert main(["plot", "convergence", str(blf), "--signals", "online_id", "--quiet",
                 "--out", str(tmp_path / "conv.png")]) == 0
    assert (tmp_path / "conv.png").stat().st_size > 0
    capsys.readouterr()


def test_resample_puts_a_jittery_can_log_on_an_even_grid_and_refuses_across_a_dropout(tmp_path, rav4_paths, capsys):
    import itertools

    log, dbc = rav4_paths
    short = write_frames(itertools.islice(can.LogReader(str(log)), 5000), tmp_path / "rav4.log")
    out = tmp_path / "even.csv"
    argv = ["decode", str(short), "--dbc", str(dbc), "--signals", "toyota_rav4_2017"]
    assert main([*argv, "--out", str(tmp_path / "raw.csv")]) == 0
    assert main([*argv, "--resample", "80", "--out", str(out)]) == 0
    raw, even = read_track_run(tmp_path / "raw.csv"), read_track_run(out)
    assert raw.time[0] == 0 and "from the first sample (log time 46408.5" in capsys.readouterr().out
    assert np.ptp(np.diff(raw.time)) > 5e-3  # bus jitter: KINEMATICS arrives 0.1-29 ms apart
    np.testing.assert_allclose(np.diff(even.time), 1 / 80, rtol=1e-6)
    np.testing.assert_allclose(even.yaw_rate, np.interp(even.time, raw.time, raw.yaw_rate), atol=1e-9)
    # a dropout longer than 0.1 s is not bridged
    frames = [m for m in can.LogReader(str(short)) if not 46409.5 < m.timestamp < 46409.8]
    holed = write_frames(frames, tmp_path / "holed.log")
    argv[1] = str(holed)
    assert main([*argv, "--resample", "80", "--out", str(out)]) == 2
    assert "would invent values across it" in capsys.readouterr().err
