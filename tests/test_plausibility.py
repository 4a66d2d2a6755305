"""Plausibility of the inputs: unit and sign slips are refused (exit 2) naming channel, slope and cause;
clean simulated runs and the real logs pass; a run without excitation is not refused."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from online_id.cli.main import main
from online_id.io.tracklog import read_track_run, write_track_run
from online_id.sim.simulator import simulate
from online_id.stream.samples import samples_from_run
from online_id.trust.plausibility import (
    CHECKS,
    ImplausibleInputError,
    StreamChecker,
    judge_run,
    parse_allow,
)
from online_id.vehicle.loader import load_vehicle
from tests.conftest import SHARED

HARO = load_vehicle("haro2008")
REVS_CSV = SHARED / "realdata" / "revs_250lm" / "revs_250lm_laps_0-400s.csv"
#: Slip runs: Haro's chirp at 80 km/h, 30 s at 200 Hz (the chirp then sweeps 0.2-4 Hz in 30 s).
SLIP_DURATION_S, SLIP_RATE_HZ = 30.0, 200.0


@pytest.fixture(scope="module")
def clean_run():
    return simulate(HARO, HARO.truth("track"), duration_s=SLIP_DURATION_S, rate_hz=SLIP_RATE_HZ, seed=3).run


def _small_steer_run(maneuver="chirp"):
    return simulate(HARO, HARO.truth("track"), duration_s=SLIP_DURATION_S, rate_hz=SLIP_RATE_HZ,
                    amplitude_rad=np.deg2rad(3.0), maneuver=maneuver, seed=4).run


#: name: (how the log is wrong, the check that must fail, words the message must hold)
SLIPS = {
    "speed in km/h": (lambda r: replace(r, speed=r.speed * 3.6), "speed_unit", ("speed", "km/h", "+0.2")),
    "yaw rate SAE sign": (lambda r: replace(r, yaw_rate=-r.yaw_rate), "yaw_sign", ("yaw_rate", "opposite sign")),
    "a_y SAE sign": (lambda r: replace(r, lateral_acceleration=-r.lateral_acceleration), "ay_slope",
                     ("lateral_acceleration", "opposite sign", "slope -1")),
    "a_y in g": (lambda r: replace(r, lateral_acceleration=r.lateral_acceleration / 9.81), "ay_slope",
                 ("lateral_acceleration", " g ", "slope +0.1")),
    "steering sign": (lambda r: replace(r, steering_wheel_angle=-r.steering_wheel_angle), "yaw_sign",
                      ("steering_wheel_angle", "opposite sign")),
    "roll sign": (lambda r: replace(r, roll_angle=-r.roll_angle), "roll", ("roll_angle", "opposite sign")),
}


@pytest.mark.parametrize("name", list(SLIPS))
def test_each_slip_is_refused_by_estimate_naming_channel_evidence_and_cause(name, clean_run, tmp_path, capsys):
    make, check, words = SLIPS[name]
    log = write_track_run(make(clean_run), tmp_path / "slip.csv")
    assert main(["estimate", str(log), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0, err  # one line
    assert "implausible input" in err and check in err.split("--allow-implausible ")[1].rstrip(")").split(",")
    for w in words:
        assert w in err, (w, err)


def test_steering_in_degrees_at_a_small_amplitude_is_refused(tmp_path, capsys):
    """3 deg logged as 3 'rad' passes the reader's 4π limit; the yaw gain is then 1/57 of the model's."""
    for maneuver in ("chirp", "sine"):
        run = _small_steer_run(maneuver)
        assert np.abs(np.rad2deg(run.steering_wheel_angle)).max() < 4 * np.pi
        log = write_track_run(replace(run, steering_wheel_angle=np.rad2deg(run.steering_wheel_angle)),
                              tmp_path / f"deg_{maneuver}.csv")
        assert main(["fit", str(log), "--quiet", "--generations", "1"]) == 2
        err = capsys.readouterr().err
        assert "steering_wheel_angle" in err and "degrees" in err and "slope +0.01" in err, err


def test_a_yaw_rate_sign_slip_names_the_yaw_rate_not_the_accelerometer(clean_run):
    report = judge_run(replace(clean_run, yaw_rate=-clean_run.yaw_rate), HARO)
    assert report.by_check("ay_slope").channel == "yaw_rate"
    assert report.by_check("yaw_sign").channel == "yaw_rate"
    report = judge_run(replace(clean_run, lateral_acceleration=-clean_run.lateral_acceleration), HARO)
    assert report.by_check("ay_slope").channel == "lateral_acceleration"
    assert report.by_check("yaw_sign").status == "ok"


def test_other_slips_are_named(clean_run):
    cases = [
        (replace(clean_run, steering_wheel_angle=clean_run.steering_wheel_angle / 16), "steering_gain", "road-wheel"),
        (replace(clean_run, roll_angle=np.rad2deg(clean_run.roll_angle) / 10), "roll", "degrees"),
        (replace(clean_run, speed=clean_run.speed * 2.2369), "speed_unit", "mph"),
    ]
    for run, check, word in cases:
        failed = {r.check: r for r in judge_run(run, HARO).failures}
        assert check in failed and word in failed[check].message, (check, [r.message for r in failed.values()])


def test_the_override_accepts_the_run_and_reports_a_warning(clean_run, tmp_path, capsys):
    log = write_track_run(replace(clean_run, speed=clean_run.speed * 3.6), tmp_path / "kmh.csv")
    assert main(["estimate", str(log), "--quiet", "--allow-implausible", "speed_unit"]) == 0
    err = capsys.readouterr().err
    assert "allowed by --allow-implausible" in err and "km/h" in err
    assert main(["estimate", str(log), "--quiet", "--allow-implausible", "yaw_sign"]) == 2  # not that check
    assert main(["estimate", str(log), "--quiet", "--allow-implausible", "all"]) == 0
    assert main(["estimate", str(log), "--quiet", "--allow-implausible", "speed"]) == 2
    assert "unknown check 'speed'" in capsys.readouterr().err
    assert parse_allow("ay_slope, roll") == ("ay_slope", "roll") and set(CHECKS) >= {"magnitude", "roll"}


def test_an_offset_is_not_a_slip(clean_run):
    """The regression has an intercept: sensor offsets are for the filter, not a reason to refuse."""
    run = replace(clean_run, lateral_acceleration=clean_run.lateral_acceleration + 0.3,
                  yaw_rate=clean_run.yaw_rate + 0.02)
    assert not judge_run(run, HARO).failures


@pytest.mark.parametrize("maneuver", ["chirp", "step", "sine"])
def test_every_builtin_simulated_run_passes(maneuver):
    for truth in ("track", "track60", "constructor"):
        for kmh in (60, 80):
            run = simulate(HARO, HARO.truth(truth), speed_mps=kmh / 3.6, maneuver=maneuver, seed=1).run
            report = judge_run(run, HARO)
            assert not report.failures, (truth, kmh, [r.message for r in report.failures])
            assert report.by_check("ay_slope").status == "ok", (truth, kmh)
            assert 0.9 < report.by_check("ay_slope").value < 1.15


def test_the_simulate_command_output_passes_estimate(tmp_path, capsys):
    log = tmp_path / "run.csv"
    assert main(["simulate", "--out", str(log), "--duration", "20", "--rate", "200", "--maneuver", "sine",
                 "--speed-kmh", "60"]) == 0
    assert main(["estimate", str(log), "--quiet"]) == 0
    assert "implausible" not in capsys.readouterr().err


def test_too_little_excitation_is_not_refused_but_said(clean_run):
    straight = replace(clean_run, steering_wheel_angle=clean_run.steering_wheel_angle * 1e-4,
                       yaw_rate=clean_run.yaw_rate * 1e-4 + np.random.default_rng(0).normal(0, 0.004, len(clean_run)),
                       lateral_acceleration=np.random.default_rng(1).normal(0, 0.05, len(clean_run)),
                       roll_angle=np.random.default_rng(2).normal(0, 5e-4, len(clean_run)))
    report = judge_run(straight, HARO)
    assert not report.failures
    notes = report.enforce()
    assert any("not enough excitation to check" in n for n in notes)
    short = judge_run(clean_run.slice(0, int(5 * SLIP_RATE_HZ)), HARO)
    assert not short.failures and "not enough data" in short.enforce()[0]


def test_the_race_car_log_passes(capsys):
    run = read_track_run(REVS_CSV)
    for car in ("revs_250lm", "haro2008"):
        report = judge_run(run, load_vehicle(car))
        assert not report.failures, [r.message for r in report.failures]
        assert 0.9 < report.by_check("ay_slope").value < 1.1  # the README: 0.99
        assert report.by_check("yaw_sign").status == "ok"


def _rav4_stream(rav4_paths, map_text=None, tmp_path=None):
    from online_id.drivers.can_log import CanLogSource, load_dbc
    from online_id.drivers.signal_map import load_signal_map

    log, dbc = rav4_paths
    smap = load_signal_map("toyota_rav4_2017")
    if map_text is not None:
        path = tmp_path / "raw_sign.toml"
        path.write_text(map_text)
        smap = load_signal_map(str(path))
    return CanLogSource(log, load_dbc(dbc), smap)


def _map_without_the_negation():
    from online_id.drivers.signal_map import builtin_map_path

    text = builtin_map_path("toyota_rav4_2017").read_text()
    assert "scale = -1.0" in text
    return text.replace("scale = -1.0", "scale = 1.0")


def test_the_rav4_can_log_passes_after_its_map_and_fails_without_the_negation(rav4_paths, tmp_path):
    car = load_vehicle("rav4_2017")
    checker = StreamChecker(car.known, car.prior, max_window_s=None)
    samples = list(checker.check(_rav4_stream(rav4_paths)))
    assert len(samples) == 4974  # every sample released, none lost by the holding
    assert not checker.report.failures
    assert 0.7 < checker.report.by_check("ay_slope").value < 1.4
    assert checker.report.by_check("yaw_sign").status == "ok"
    with pytest.raises(ImplausibleInputError, match="lateral_acceleration.*opposite sign"):
        list(StreamChecker(car.known, car.prior, max_window_s=None).check(
            _rav4_stream(rav4_paths, _map_without_the_negation(), tmp_path)))


def test_estimate_on_the_rav4_can_log_refuses_the_raw_sign(rav4_paths, tmp_path, capsys):
    log, dbc = rav4_paths
    path = tmp_path / "raw_sign.toml"
    path.write_text(_map_without_the_negation())
    assert main(["estimate", str(log), "--dbc", str(dbc), "--signals", str(path), "--vehicle", "rav4_2017"]) == 2
    err = capsys.readouterr().err
    assert "lateral_acceleration" in err and "opposite sign" in err and "--allow-implausible ay_slope" in err
    assert main(["estimate", str(log), "--dbc", str(dbc), "--signals", "toyota_rav4_2017",
                 "--vehicle", "rav4_2017"]) == 0
    assert "implausible" not in capsys.readouterr().err


def test_a_stream_is_held_until_judged_and_a_slip_releases_nothing(clean_run):
    released = []
    checker = StreamChecker(HARO.known, HARO.prior, max_window_s=20.0)
    bad = replace(clean_run, lateral_acceleration=clean_run.lateral_acceleration / 9.81)
    with pytest.raises(ImplausibleInputError, match="in g"):
        for s in checker.check(samples_from_run(bad)):
            released.append(s)
    assert released == []
    # a clean stream: judged within the window, every sample released in order
    checker = StreamChecker(HARO.known, HARO.prior, max_window_s=20.0)
    out = list(checker.check(samples_from_run(clean_run)))
    assert len(out) == len(clean_run) and out[-1].time == clean_run.time[-1]
    assert checker.report is not None and checker.report.window_s <= 20.0 and not checker.report.failures
    # live (hold=False): samples pass at once, the verdict still comes within the window and raises
    passed = []
    with pytest.raises(ImplausibleInputError, match="in g"):
        for s in StreamChecker(HARO.known, HARO.prior, max_window_s=20.0, hold=False).check(samples_from_run(bad)):
            passed.append(s)
    assert 15.0 <= passed[-1].time <= 20.0


def test_a_stream_checks_magnitude_per_sample(clean_run):
    bad = clean_run.slice(0, 400)
    bad = replace(bad, yaw_rate=np.where(np.arange(400) == 300, 9.0, bad.yaw_rate))
    with pytest.raises(ImplausibleInputError, match=r"yaw_rate = 9 rad/s at t = 1.500 s.*magnitude"):
        list(StreamChecker(HARO.known, HARO.prior).check(samples_from_run(bad)))
    assert len(list(StreamChecker(HARO.known, HARO.prior, allow=("magnitude",)).check(samples_from_run(bad)))) == 400


def test_the_race_car_vehicle_loads():
    car = load_vehicle("revs_250lm")
    k = car.known
    assert (k.M, k.l1, k.l2, k.steering_ratio) == (982.0, 1.33, 1.07, 13.529)
    assert car.prior.Mzz == 1600.0 and 0 < k.ms < k.M
    assert min(car.prior_relative_std.to_vector()) >= 0.5  # guesses: wide prior


def _listen_to(run, capsys, *extra):
    """``online-id listen`` on an in-process python-can virtual bus that carries ``run`` as own frames."""
    import threading
    import time

    import can
    from online_id.drivers.frames import frames_from_run

    channel = f"plausibility-{time.monotonic_ns()}"
    frames = list(frames_from_run(run))

    def sender():
        from can.interfaces.virtual import channels

        deadline = time.monotonic() + 60
        while not channels.get(channel) and time.monotonic() < deadline:  # until the listener's bus exists
            time.sleep(0.05)
        with can.Bus(interface="virtual", channel=channel) as tx:
            for f in frames:
                tx.send(f)

    th = threading.Thread(target=sender)
    th.start()
    try:
        rc = main(["listen", "--interface", "virtual", "--channel", channel, "--idle-timeout", "1",
                   "--start-timeout", "20", *extra])
    finally:
        th.join()
    return rc, capsys.readouterr()


def test_listen_judges_the_first_seconds_and_aborts_on_a_slip(clean_run, capsys, record_bus):
    record_bus("python-can virtual (in-process)")
    run = clean_run.slice(0, int(25 * SLIP_RATE_HZ))
    rc, out = _listen_to(replace(run, yaw_rate=-run.yaw_rate), capsys)
    assert rc == 2 and "yaw_rate" in out.err and "opposite sign" in out.err, out.err
    rc, out = _listen_to(replace(run, yaw_rate=-run.yaw_rate), capsys, "--allow-implausible", "all")
    assert rc == 0 and "allowed by --allow-implausible" in out.err
    received = int(out.out.split(" samples from virtual")[0].split("\n")[-1])
    assert received >= 0.99 * len(run)  # the held samples reached the estimator (the bus may drop a frame)
    rc, out = _listen_to(run, capsys)
    assert rc == 0 and "implausible" not in out.err
