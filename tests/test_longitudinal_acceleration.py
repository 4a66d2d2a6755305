"""Longitudinal acceleration: logged by the simulator with a braking and traction profile, read from a log with
its unit checked against the speed's change, and said what uses it (issue 38, items 2 and 5; the effect that moves
the axle loads with it: tests/test_load_transfer.py)."""

from __future__ import annotations

import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest

from online_id.errors import LogFormatError
from online_id.io.tracklog import (
    longitudinal_acceleration_of,
    longitudinal_acceleration_slope,
    read_track_run,
    write_track_run,
)
from online_id.model.lateral import BETA, R
from online_id.sim.maneuvers import SpeedProfile
from online_id.sim.simulator import SensorNoise, simulate
from online_id.units import G
from online_id.vehicle import load_vehicle
from tests.conftest import SHARED

CAR = load_vehicle("haro2008")
TRUTH = CAR.truth("track")
RACE = SHARED / "realdata" / "revs_250lm" / "revs_250lm_laps_0-400s.csv"
BRAKING = "0:100,4:60,8:100,12:60"


def test_speed_profile_passes_its_breakpoints_and_its_acceleration_is_the_derivative():
    p = SpeedProfile.parse(BRAKING)
    np.testing.assert_allclose(p.speed([0, 4, 8, 12]), np.array([100, 60, 100, 60]) / 3.6, rtol=1e-12)
    t = np.linspace(0.1, 11.9, 500)
    h = 1e-5
    numeric = (p.speed(t + h) - p.speed(t - h)) / (2 * h)
    np.testing.assert_allclose(p.acceleration(t), numeric, atol=1e-6)
    # shape-preserving: never outside the breakpoints' speeds, and braking from 100 to 60 km/h in 4 s peaks
    # above the mean deceleration (2.78 m/s²) but stays a car's (under 1 g)
    v = p.speed(np.linspace(0, 12, 2001))
    assert v.min() >= 60 / 3.6 - 1e-9 and v.max() <= 100 / 3.6 + 1e-9
    assert 40 / 3.6 / 4 < -p.acceleration(np.linspace(0, 4, 401)).min() < G
    # held after the last breakpoint, with no acceleration
    assert p.speed(20.0) == pytest.approx(60 / 3.6) and p.acceleration(20.0) == 0.0


@pytest.mark.parametrize("text, says", [("0:100,4", "not TIME_S:SPEED_KMH"), ("0:100,0:60", "increase strictly"),
                                        ("0:100,4:-5", "positive"), ("a:b", "not TIME_S:SPEED_KMH")])
def test_a_bad_speed_profile_is_refused_with_what_is_wrong(text, says):
    with pytest.raises(ValueError, match=says):
        SpeedProfile.parse(text)


def test_simulated_longitudinal_acceleration_is_what_a_body_fixed_accelerometer_reads():
    """a_x = dV/dt − V β r, the exact derivative of the profile at the logged times, from the car's own states."""
    p = SpeedProfile.parse(BRAKING)
    sim = simulate(CAR, TRUTH, duration_s=12, rate_hz=100, speed_mps=p, maneuver="sine", frequency_hz=0.5,
                   amplitude_rad=np.deg2rad(40), noise=SensorNoise.none(), longitudinal_acceleration=True)
    run = sim.run
    np.testing.assert_allclose(run.speed, p.speed(run.time), rtol=1e-12)
    expected = p.acceleration(run.time) - run.speed * sim.states[:, BETA] * sim.states[:, R]
    np.testing.assert_allclose(run.longitudinal_acceleration, expected, atol=1e-12)
    assert -run.longitudinal_acceleration.min() > 0.3 * G  # braking and traction a race engineer would call real
    assert run.longitudinal_acceleration.max() > 0.2 * G
    assert np.abs(sim.states[:, BETA] * sim.states[:, R] * run.speed).max() > 0.01  # the v_y·r term is there
    assert run.meta["speed_profile"]["speed_mps"][1] == pytest.approx(60 / 3.6)


def test_the_other_channels_are_the_same_with_longitudinal_acceleration_or_without():
    """Its noise is drawn after every other channel's: adding the column changes no other number."""
    kw = dict(duration_s=4, rate_hz=100, speed_mps=SpeedProfile.parse("0:90,4:70"), seed=3, lateral_velocity=True)
    a = simulate(CAR, TRUTH, **kw).run
    b = simulate(CAR, TRUTH, **kw, longitudinal_acceleration=True).run
    assert a.longitudinal_acceleration is None and b.longitudinal_acceleration is not None
    for c in a.channels:
        np.testing.assert_array_equal(getattr(a, c), getattr(b, c), err_msg=c)


def test_a_speed_profile_integrated_finely_differs_from_one_held_at_the_logged_speeds():
    """Fine integration evaluates the profile between the logged samples (not a line through them)."""
    p = SpeedProfile.parse("0:100,1:60,2:100")
    fine = simulate(CAR, TRUTH, duration_s=2, rate_hz=25, speed_mps=p, noise=SensorNoise.none())
    fine_array = simulate(CAR, TRUTH, duration_s=2, rate_hz=25, speed_mps=p.speed(fine.run.time),
                          noise=SensorNoise.none())
    np.testing.assert_array_equal(fine.run.speed, fine_array.run.speed)
    assert not np.array_equal(fine.run.yaw_rate, fine_array.run.yaw_rate)
    np.testing.assert_allclose(fine.run.yaw_rate, fine_array.run.yaw_rate, atol=2e-3)


def test_the_column_round_trips_through_the_csv_and_is_checked_for_g_and_sign(tmp_path):
    sim = simulate(CAR, TRUTH, duration_s=12, rate_hz=100, speed_mps=SpeedProfile.parse(BRAKING), seed=1,
                   longitudinal_acceleration=True)
    path = write_track_run(replace(sim.run, meta={}), tmp_path / "brake.csv")
    back = read_track_run(path)
    assert back.channels[-1] == "longitudinal_acceleration"
    np.testing.assert_allclose(back.longitudinal_acceleration, sim.run.longitudinal_acceleration, rtol=1e-9)
    slope, corr = longitudinal_acceleration_slope(back.time, back.speed, back.longitudinal_acceleration)
    assert slope == pytest.approx(1.0, abs=0.05) and corr > 0.99

    in_g = write_track_run(replace(sim.run, meta={}, longitudinal_acceleration=sim.run.longitudinal_acceleration / G),
                           tmp_path / "in_g.csv")
    with pytest.raises(LogFormatError, match=r"in_g.csv: column 'longitudinal_acceleration'.*in g instead of m/s²"):
        read_track_run(in_g)
    turned = write_track_run(replace(sim.run, meta={}, longitudinal_acceleration=-sim.run.longitudinal_acceleration),
                             tmp_path / "turned.csv")
    with pytest.raises(LogFormatError, match="sign is turned"):
        read_track_run(turned)


def test_at_constant_speed_the_check_has_nothing_to_judge_by_and_says_nothing(tmp_path):
    sim = simulate(CAR, TRUTH, duration_s=10, rate_hz=100, seed=2, longitudinal_acceleration=True)
    run = sim.run
    assert longitudinal_acceleration_slope(run.time, run.speed, run.longitudinal_acceleration / G) is None
    read_track_run(write_track_run(replace(run, meta={}, longitudinal_acceleration=run.longitudinal_acceleration / G),
                                   tmp_path / "flat.csv"))


def test_dv_dt_stands_in_when_the_column_is_not_logged_and_it_is_said():
    sim = simulate(CAR, TRUTH, duration_s=12, rate_hz=100, speed_mps=SpeedProfile.parse(BRAKING),
                   noise=SensorNoise.none(), longitudinal_acceleration=True)
    logged, how = longitudinal_acceleration_of(sim.run)
    assert how == "logged longitudinal_acceleration"
    derived, how = longitudinal_acceleration_of(replace(sim.run, longitudinal_acceleration=None))
    assert "dV/dt from the speed" in how
    # the central difference of a 100 Hz speed, against the accelerometer's dV/dt − v_y r: within the v_y r term
    np.testing.assert_allclose(derived, logged, atol=np.abs(sim.run.speed * sim.states[:, BETA]
                                                            * sim.states[:, R]).max() + 0.02)


def test_the_race_car_logs_an_accelerometer_in_m_s2_along_its_speed():
    run = read_track_run(RACE)
    assert run.longitudinal_acceleration is not None
    slope, corr = longitudinal_acceleration_slope(run.time, run.speed, run.longitudinal_acceleration)
    assert 0.95 < slope < 1.15 and corr > 0.99  # (measured 1.05, 0.998)
    assert run.longitudinal_acceleration.min() < -0.9 * G  # braking up to 1 g, as its README says


def test_simulate_command_writes_the_column_and_estimate_says_what_uses_it(tmp_path):
    out = tmp_path / "brake.csv"
    cmd = [sys.executable, "-m", "online_id.cli.main", "simulate", "--out", str(out), "--duration", "8",
           "--rate", "100", "--speed-profile", "0:100,4:60,8:100", "--longitudinal-acceleration", "--maneuver", "sine",
           "--frequency", "0.5"]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "braking to" in done.stdout and "60-100 km/h" in done.stdout
    assert read_track_run(out).longitudinal_acceleration is not None
    est = subprocess.run([sys.executable, "-m", "online_id.cli.main", "estimate", str(out), "--no-polish"],
                         capture_output=True, text=True, timeout=300)
    assert est.returncode == 0, est.stderr
    assert "longitudinal_acceleration read" in est.stderr
    assert "load_transfer, combined_slip, load_sensitivity and downforce follow it" in est.stderr
    assert "do not use it" in est.stderr  # (the base model the estimate ran does not)
    bad = subprocess.run(cmd[:6] + ["--speed-profile", "0:100,4"], capture_output=True, text=True, timeout=300)
    assert bad.returncode == 2 and "--speed-profile" in bad.stderr and "TIME_S:SPEED_KMH" in bad.stderr
