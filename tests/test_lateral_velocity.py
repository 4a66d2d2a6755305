"""Measured sideslip (issue 38 item 1): the lateral velocity at the centre of gravity as an output.

Runs are simulated as a logger sees a car (integrated at 10 kHz, logged at 100 Hz) with the lateral velocity
logged beside the other channels (``simulate(..., lateral_velocity=True)``, 0.02 m/s noise).
"""

from __future__ import annotations

import json
import subprocess
import sys
import warnings
from dataclasses import replace

import numpy as np
import pytest

from online_id.errors import OnlineIdError, VehicleFileError
from online_id.estimation import make_estimator, run_estimator
from online_id.io.tracklog import lateral_velocity_at_cg, write_track_run
from online_id.model.lateral import BETA, OUTPUT_NAMES, VY, continuous_matrices, outputs_from_continuous
from online_id.sim.simulator import simulate
from online_id.stream.samples import MEASURED_CHANNELS, SampleArrays
from online_id.trust.check import check_run
from online_id.trust.consistency import TEST_ALPHA, significance
from online_id.vehicle import load_vehicle
from online_id.vehicle.loader import parse_vehicle
from online_id.workflows.estimate_job import estimate

CAR = load_vehicle("haro2008")
TRUTH = CAR.truth("track")
FOUR = ("yaw_rate", "roll_angle", "roll_rate", "lateral_acceleration")


def _run(**kw):
    kw = {"rate_hz": 100.0, "seed": 0, "truth_name": "track", "lateral_velocity": True, **kw}
    return simulate(CAR, TRUTH, **kw).run


def test_the_channel_is_the_fifth_output_and_the_filters_work_it_per_unit_speed():
    assert OUTPUT_NAMES[VY] == MEASURED_CHANNELS[VY] == "lateral_velocity"
    V = np.array([10.0, 30.0])
    Ac, Bc = continuous_matrices(TRUTH, V, CAR.known)
    C, D = outputs_from_continuous(Ac, Bc, V)
    Cu, Du = outputs_from_continuous(Ac, Bc, V, per_unit_speed=True)
    expected = np.zeros((2, 6))
    expected[:, BETA] = V
    np.testing.assert_array_equal(C[:, VY], expected)  # v_y = V β
    expected[:, BETA] = 1.0
    np.testing.assert_array_equal(Cu[:, VY], expected)  # the filters': β
    np.testing.assert_array_equal(C[:, :VY], Cu[:, :VY])  # the other rows untouched
    assert not D[:, VY].any()


def test_logging_it_leaves_the_other_channels_as_they_were():
    """The same seed gives the same noise on the four channels with the lateral velocity logged or not (its noise
    is drawn after theirs), so every run made before issue 38 is made again bit for bit."""
    a = simulate(CAR, TRUTH, rate_hz=100.0, duration_s=5.0, seed=3).run
    b = simulate(CAR, TRUTH, rate_hz=100.0, duration_s=5.0, seed=3, lateral_velocity=True).run
    assert a.lateral_velocity is None
    for c in FOUR:
        np.testing.assert_array_equal(getattr(a, c), getattr(b, c))
    sim = simulate(CAR, TRUTH, rate_hz=100.0, duration_s=20.0, seed=3, lateral_velocity=True)
    noise = sim.run.lateral_velocity - sim.outputs[:, VY]
    assert abs(noise.std() - 0.02) < 0.002 and abs(noise.mean()) < 0.002
    # v_y = V β with the sideslip the car really had
    np.testing.assert_allclose(sim.outputs[:, VY], sim.run.speed * sim.states[:, BETA], rtol=0, atol=1e-12)


@pytest.mark.parametrize("filter_name", ["ekf", "ukf"])
def test_filters_recover_the_car_with_it(filter_name):
    run = _run(duration_s=30.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = run_estimator(make_estimator(CAR, filter_name), SampleArrays.from_run(run))
    err = res.parameters.to_vector() / TRUTH.to_vector() - 1
    assert np.abs(err).max() < 0.01, dict(zip(res.parameters.to_dict(), np.round(100 * err, 2)))
    assert res.consistency["consistent"] is True, res.consistency["reasons"]
    size = res.consistency["innovations"]["channels"]["lateral_velocity"]["rms_ratio"]
    assert 0.8 < size < 1.25  # its innovations the size its noise (0.02 m/s, divided by V inside) says


def test_a_weakly_excited_run_is_pinned_by_it():
    """The acceptance: a short, weakly excited run (a 5° steering-wheel step at 150 km/h, 0.13 g, 10 s): with the
    column, σ of Mzz, D1, D2 at least 2× smaller than without it, every parameter within 3σ of the truth. The
    Cramér-Rao bound of this run says Mzz 2.5×, D1 8.5×, D2 10× (check's -v_y column)."""
    run = _run(duration_s=10.0, maneuver="step", amplitude_rad=np.deg2rad(5.0), speed_mps=150 / 3.6)
    with_it = estimate(run, vehicle=CAR).result
    without = estimate(run, vehicle=CAR, channels=FOUR).result
    assert "lateral_velocity" in with_it.to_json_dict()["channels"]
    assert "lateral_velocity" not in without.to_json_dict()["channels"]
    for name in ("Mzz", "D1", "D2"):
        i = list(TRUTH.to_dict()).index(name)
        assert without.std[i] >= 2.0 * with_it.std[i], (name, without.std[i], with_it.std[i])
    z = (with_it.parameters.to_vector() - TRUTH.to_vector()) / with_it.std
    assert np.abs(z).max() <= 3.0, np.round(z, 2)


@pytest.mark.parametrize("filter_name", ["ekf", "ukf"])
def test_saturating_tyres_with_it(filter_name):
    """μ 0.7 at 0.79 g (60° chirp), logged at 100 Hz with the lateral velocity: the tyre filters take it too."""
    from online_id.effects import parse_effect

    run = simulate(CAR, TRUTH, rate_hz=100.0, duration_s=20.0, seed=1, truth_name="track", lateral_velocity=True,
                   amplitude_rad=np.deg2rad(60.0), effects=[parse_effect("tire_saturation=0.7")]).run
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = estimate(run, vehicle=CAR, filter=filter_name, effects=["tire_saturation"], polish=False).result
    err = res.parameters.to_vector() / TRUTH.to_vector() - 1
    assert np.abs(err).max() < 0.02, np.round(100 * err, 2)
    mu = res.to_json_dict()["effects"]["tire_saturation"]["mu"]["value"]
    assert abs(mu / 0.7 - 1) < 0.02
    assert res.consistency["consistent"] is True, res.consistency["reasons"]


def test_a_log_with_it_and_no_roll_estimates_what_it_determines():
    """The race car's channels (yaw rate, a_y, lateral velocity; no roll): every parameter within 3σ of the truth
    (the roll ones as far as a_y's roll coupling informs them)."""
    run = replace(_run(duration_s=30.0), roll_angle=None, roll_rate=None)
    res = estimate(run, vehicle=CAR).result
    out = res.to_json_dict()
    assert out["channels"] == ["yaw_rate", "lateral_acceleration", "lateral_velocity"]
    z = (res.parameters.to_vector() - TRUTH.to_vector()) / res.std
    assert np.abs(z).max() <= 3.0, np.round(z, 2)
    assert res.consistency["consistent"] is True, res.consistency["reasons"]


def test_a_sensor_ahead_of_the_cg_is_moved_there(tmp_path):
    """[sensors] lateral_velocity_x_m: a sensor 1.5 m ahead reads v_y + 1.5·r; moved back, the estimate is the one
    of the run at the CG (to the yaw rate's noise times 1.5 m)."""
    at_cg = _run(duration_s=20.0)
    x_s = 1.5
    ahead = replace(at_cg, lateral_velocity=at_cg.lateral_velocity + x_s * at_cg.yaw_rate)
    text = (load_vehicle_text() + f"\n[sensors]\nlateral_velocity_x_m = {x_s}\n")
    car_ahead = parse_vehicle(text, source="test")
    assert car_ahead.sensor_position("lateral_velocity_x_m") == x_s and CAR.sensor_position("lateral_velocity_x_m") == 0
    moved = lateral_velocity_at_cg(ahead, x_s)
    np.testing.assert_allclose(moved.lateral_velocity, at_cg.lateral_velocity, atol=1e-12)
    assert lateral_velocity_at_cg(moved, x_s) is moved  # once only
    a = estimate(at_cg, vehicle=CAR, polish=False).result
    b = estimate(ahead, vehicle=car_ahead, polish=False).result
    c = estimate(ahead, vehicle=CAR, polish=False).result  # not moved: the model cannot make that sideslip
    np.testing.assert_allclose(b.parameters.to_vector(), a.parameters.to_vector(), rtol=1e-12)
    assert c.consistency["consistent"] is False
    with pytest.raises(VehicleFileError, match="lateral_velocity_x_m"):
        parse_vehicle(load_vehicle_text() + "\n[sensors]\nlateral_velocity_x_m = 1500\n", source="test")
    with pytest.raises(VehicleFileError, match="unknown key sensors.gps_x_m"):
        parse_vehicle(load_vehicle_text() + "\n[sensors]\ngps_x_m = 1\n", source="test")


def test_streamed_samples_are_moved_too():
    """A streamed source (CAN log, live bus) moves each sample's lateral velocity with its yaw rate."""
    from online_id.drivers.base import SampleSource

    from online_id.stream.samples import samples_from_run

    run = _run(duration_s=1.0)

    class Stream(SampleSource):
        def _samples(self):
            yield from samples_from_run(run)

    src = Stream()
    src.move_lateral_velocity(2.0)
    got = [s.lateral_velocity for s in src]
    np.testing.assert_allclose(got, run.lateral_velocity - 2.0 * run.yaw_rate, rtol=0, atol=1e-15)


def test_check_shows_what_it_adds_and_what_it_would_add():
    run = _run(duration_s=10.0, maneuver="step", amplitude_rad=np.deg2rad(5.0), speed_mps=150 / 3.6)
    rep = check_run(run, CAR, theta=TRUTH)
    assert "lateral_velocity" in rep.crlb.channels
    without = next(c for c in rep.candidates if c.label == "-v_y")
    ratio = without.crlb_relative_std / rep.crlb.crlb_relative_std
    assert ratio[0] > 2.0 and ratio[2] > 5.0 and ratio[3] > 5.0  # Mzz, D1, D2
    rep4 = check_run(replace(run, lateral_velocity=None), CAR, theta=TRUTH)
    plus = next(c for c in rep4.candidates if c.label == "+v_y")
    # (at the log's noise floor: the +v_y candidate takes the configured 0.02 m/s, the run with it its measured floor)
    np.testing.assert_allclose(plus.crlb_relative_std, rep.crlb.crlb_relative_std, rtol=0.03)


def test_the_verdicts_budget_is_shared_over_the_channels_judged():
    assert significance(4) == TEST_ALPHA == significance(2)  # as before: at least the four channels' share
    assert significance(5) == pytest.approx(TEST_ALPHA * 4 / 5)


def test_no_offset_state_on_it():
    """A constant offset in m/s is not how a lateral-velocity sensor errs (a yaw misalignment reads ε·V): the
    effect refuses the channel by name, and a biased lateral velocity's next step says what to look at."""
    from online_id.effects import parse_effect
    from online_id.trust.consistency import next_steps

    with pytest.raises(OnlineIdError, match="lateral_velocity"):
        parse_effect("sensor_bias=lateral_velocity:0.1")
    steps = next_steps({"biased": ["lateral_velocity"]})
    assert [s["lever"] for s in steps] == ["sideslip_sensor"]
    assert "lateral_velocity_x_m" in steps[0]["because"]


def test_cli_takes_it(tmp_path):
    """simulate --lateral-velocity writes the column; estimate --channels takes it by name, and lists it."""
    log = tmp_path / "vy.csv"
    cli = [sys.executable, "-m", "online_id.cli.main"]
    subprocess.run(cli + ["simulate", "--out", str(log), "--rate", "100", "--duration", "20", "--lateral-velocity"],
                   check=True, capture_output=True)
    assert open(log).readline().strip().endswith("lateral_velocity")
    out = tmp_path / "e.json"
    subprocess.run(cli + ["estimate", str(log), "--channels", "yaw_rate,lateral_acceleration,lateral_velocity",
                          "--quiet", "--no-polish", "--json", str(out)], check=True, capture_output=True)
    data = json.loads(out.read_text())
    assert data["channels"] == ["yaw_rate", "lateral_acceleration", "lateral_velocity"]
    assert "lateral_velocity" in data["innovation_rms"]


def load_vehicle_text() -> str:
    from importlib import resources

    return (resources.files("online_id.vehicle") / "data" / "haro2008.toml").read_text(encoding="utf-8")


def test_write_and_read_keep_it(tmp_path):
    from online_id.io.tracklog import read_track_run

    run = _run(duration_s=2.0)
    path = write_track_run(run, tmp_path / "r.csv")
    np.testing.assert_allclose(read_track_run(path).lateral_velocity, run.lateral_velocity, rtol=1e-9)
