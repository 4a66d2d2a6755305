"""online-id check: what a run can tell before any estimate, and which manoeuvre would tell the rest."""

from __future__ import annotations

import json

import numpy as np
import pytest

from online_id.cli.main import main
from online_id.io.tracklog import TrackRun, write_track_run
from online_id.sim.simulator import SensorNoise, simulate
from online_id.trust.check import DETERMINED_RELATIVE_STD, check_run, noise_floor, steering_spectrum
from online_id.trust.identifiability import fisher_information
from online_id.vehicle import PARAMETER_NAMES, load_vehicle

NOISE = {"yaw_rate": 0.004, "roll_angle": 0.0005, "roll_rate": 0.004, "lateral_acceleration": 0.05}


@pytest.fixture(scope="module")
def car():
    return load_vehicle("haro2008")


def _without_roll(run: TrackRun) -> TrackRun:
    return TrackRun(time=run.time, steering_wheel_angle=run.steering_wheel_angle, speed=run.speed,
                    yaw_rate=run.yaw_rate, lateral_acceleration=run.lateral_acceleration, source="no roll")


def test_a_chirp_with_every_channel_determines_everything(car):
    run = simulate(car, car.truth("track"), duration_s=20.0, rate_hz=200.0, seed=1, lateral_velocity=True).run
    rep = check_run(run, car, noise_std=NOISE)
    assert rep.not_determined == [] and rep.channels_missing == []
    assert np.all(rep.crlb.crlb_relative_std < DETERMINED_RELATIVE_STD)
    assert rep.speed["min"] == pytest.approx(80 / 3.6) and rep.speed["below_min_speed_fraction"] == 0
    in_sweep = sum(b.power_fraction for b in rep.bands if 0.2 <= b.low_hz and b.high_hz <= 4.0)
    assert in_sweep > 0.95 and rep.steering["above_1hz_fraction"] > 0.5
    assert rep.rate_hz == pytest.approx(200.0) and rep.gaps == ()
    assert rep.advice[0].startswith("every parameter is determined")


def test_the_bound_is_the_identifiability_modules(car):
    run = simulate(car, car.truth("track"), duration_s=5.0, rate_hz=200.0, seed=1).run
    rep = check_run(run, car, noise_std=NOISE)
    direct = fisher_information(car, car.prior, run, NOISE)
    np.testing.assert_allclose(rep.crlb.crlb_relative_std, direct.crlb_relative_std, rtol=1e-3)


def test_the_bound_takes_the_steering_between_samples(car):
    """check and the Fisher information with the cubic between samples (issue 36): the sensitivities are central
    differences of the exact steps of that curve (the per-sample reference, tests/intersample_reference.py, to 1e-6
    of their range: the differences' own round-off); the report says which curve it took."""
    from intersample_reference import reference_run

    from online_id.trust.identifiability import output_sensitivities

    run = simulate(car, car.truth("track"), duration_s=2.0, rate_hz=50.0, seed=1).run
    sens = output_sensitivities(car, car.prior, run, intersample="cubic")
    base, h = car.prior.to_vector(), 1e-5
    for i in (0, 6):  # Mzz, b1
        up, down = base.copy(), base.copy()
        up[i] *= np.exp(h)
        down[i] *= np.exp(-h)
        ref = (reference_run(up, car.known, run.steering_wheel_angle, run.speed, 0.02, "cubic")[1]
               - reference_run(down, car.known, run.steering_wheel_angle, run.speed, 0.02, "cubic")[1]) / (2 * h)
        assert np.all(np.abs(sens[:, :, i] - ref).max(axis=0) <= 1e-6 * np.abs(ref).max(axis=0) + 1e-12)
    rep = check_run(run, car, noise_std=NOISE, intersample="cubic")
    assert rep.to_json_dict()["crlb"]["intersample"] == "cubic"
    cubic = fisher_information(car, car.prior, run, NOISE, intersample="cubic")
    held = fisher_information(car, car.prior, run, NOISE, intersample="hold")
    assert not np.allclose(cubic.information, held.information, rtol=1e-6)


def test_slow_steering_without_roll_names_what_is_missing_and_what_would_inform_it(car):
    sim = simulate(car, car.truth("track"), duration_s=20.0, rate_hz=100.0, maneuver="sine",
                   amplitude_rad=np.deg2rad(10), frequency_hz=0.2, seed=1)
    rep = check_run(_without_roll(sim.run), car, noise_std=NOISE)
    missing = set(rep.not_determined)
    assert {"b1", "b2"} <= missing, rep.text()
    assert rep.channels_missing[:2] == ["roll_angle", "roll_rate"]
    labels = [c.label for c in rep.candidates]
    assert labels == ["+roll", "+chirp", "+chirp+roll"]
    both = rep.candidates[-1]
    assert set(both.newly_determined) == missing, rep.text()  # the chirp with roll channels informs it all
    chirp = rep.candidates[1]
    assert {"b1", "b2"} <= set(chirp.newly_determined)
    for n in missing:  # every missing parameter gets a line of advice with the candidate's bound
        assert any(a.startswith(f"{n}: bound") and "would bring it to" in a for a in rep.advice), rep.advice
    assert any("above 1 Hz" in a for a in rep.advice)
    assert rep.steering["f95_hz"] == pytest.approx(0.2, abs=0.15)
    data = json.loads(json.dumps(rep.to_json_dict()))
    assert data["not_determined"] == rep.not_determined
    assert set(data["crlb"]["relative_std"]) == set(PARAMETER_NAMES)


def test_the_logs_own_noise_decides_when_it_is_larger(car):
    sim = simulate(car, car.truth("track"), duration_s=20.0, rate_hz=200.0, seed=1,
                   noise=SensorNoise(lateral_acceleration=1.0))
    rep = check_run(sim.run, car, noise_std=NOISE)
    assert rep.noise_floor["lateral_acceleration"] == pytest.approx(1.0, rel=0.1)
    assert np.all(rep.crlb_at_noise_floor.crlb_relative_std >= rep.crlb.crlb_relative_std)
    noisier = next(a for a in rep.advice if "noisier than the filter assumes" in a)
    assert "lateral_acceleration (" in noisier and "yaw_rate" not in noisier, noisier


def test_steering_spectrum_puts_a_sine_in_its_band():
    t = np.arange(0, 60, 0.01)
    bands, summary = steering_spectrum(0.1 + 0.05 * np.sin(2 * np.pi * 1.5 * t), 100.0)
    band = next(b for b in bands if b.low_hz == 1.0)
    assert band.power_fraction > 0.95 and band.rms_rad == pytest.approx(0.05 / np.sqrt(2), rel=0.05)
    assert summary["f95_hz"] == pytest.approx(1.5, abs=0.15)  # 0.1 Hz bins; the window leaks into the next
    assert summary["max_abs_rad"] == pytest.approx(0.15)


def test_noise_floor_of_white_noise():
    y = np.random.default_rng(0).standard_normal(20000) * 0.3 + 5.0
    assert noise_floor(y) == pytest.approx(0.3, rel=0.03)


def test_cli_check_writes_json_and_rejects_bad_input(tmp_path, capsys):
    car = load_vehicle("haro2008")
    sim = simulate(car, car.truth("track"), duration_s=10.0, rate_hz=100.0, seed=2)
    log = write_track_run(_without_roll(sim.run), tmp_path / "run.csv")
    out = tmp_path / "check.json"
    assert main(["check", str(log), "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    assert {"sampling", "channels", "speed_mps", "steering", "lateral_acceleration", "crlb", "candidates",
            "advice", "not_determined"} <= set(data)
    assert data["channels"]["missing"][:2] == ["roll_angle", "roll_rate"]
    text = capsys.readouterr().out
    assert "Cramér-Rao bound" in text and "+chirp" in text
    assert main(["check", str(log), "--json", str(tmp_path / "nope" / "c.json")]) == 2
    assert main(["check", str(tmp_path / "missing.csv")]) == 2


def _strict(text: str) -> dict:
    """json.loads that refuses what RFC 8259 does not have (Infinity, NaN), as strict parsers do."""
    def refuse(constant):
        raise ValueError(f"not JSON: {constant}")

    return json.loads(text, parse_constant=refuse)


def test_check_json_of_a_straight_line_is_strict_json_with_null_and_why(tmp_path):
    """A straight line informs nothing: the condition number is infinite. It was written as Infinity."""
    car = load_vehicle("haro2008")
    log = write_track_run(simulate(car, car.truth("track"), duration_s=20.0, rate_hz=100.0, seed=1,
                                   amplitude_rad=0.0).run, tmp_path / "straight.csv")
    out = tmp_path / "check.json"
    assert main(["check", str(log), "--json", str(out)]) == 0
    data = _strict(out.read_text())
    assert data["crlb"]["condition_number"] is None and "infinite" in data["null_means"]
    assert set(data["not_determined"]) == set(PARAMETER_NAMES)
    assert all(v is None for v in data["crlb"]["relative_std"].values())
    assert not any(p.name.endswith(".tmp") for p in tmp_path.iterdir())  # written atomically, nothing left over
    assert main(["check", str(log), "--json", str(log)]) == 2 and log.read_text().startswith("time,")  # an input


def test_check_reads_a_can_log_through_its_dbc_as_estimate_does(tmp_path, rav4_paths, capsys):
    """check refused --dbc/--signals: a CAN log had to be decoded first."""
    log, dbc = rav4_paths
    out = tmp_path / "check.json"
    assert main(["check", str(log), "--dbc", str(dbc), "--signals", "toyota_rav4_2017", "--vehicle", "rav4_2017",
                 "--json", str(out)]) == 0
    data = _strict(out.read_text())
    assert data["samples"] == 4974  # every KINEMATICS frame, as estimate decodes the log
    assert data["channels"]["present"] == ["yaw_rate", "lateral_acceleration"]
    assert "D1" not in data["not_determined"] and "Kro" in data["not_determined"]  # weak excitation, no roll
    assert "decoded 4974 samples" in capsys.readouterr().err


# -- single-sample input glitches (issue 39) -----------------------------------------------------------------
def _with_spikes(run, spikes):
    from dataclasses import replace

    steering = run.steering_wheel_angle.copy()
    for i, deg in spikes:
        steering[i] += np.radians(deg)
    return replace(run, steering_wheel_angle=steering)


def test_three_steering_spikes_no_longer_make_a_gentle_run_determine_everything(car):
    """A gentle 0.2 Hz, 2° sine leaves Mzz, Mxx, Aro, b1 and b2 undetermined; on main three single-sample
    steering spikes (100°, 115°, 170°) made check call every parameter determined. They are found, said and
    mended first."""
    from online_id.workflows import check

    run = simulate(car, car.truth("track"), duration_s=20.0, rate_hz=100.0, maneuver="sine",
                   amplitude_rad=np.radians(2.0), frequency_hz=0.2, seed=5).run
    at = (500, 1100, 1700)
    clean = check(run).result
    spiky = check(_with_spikes(run, zip(at, (100.0, 115.0, 170.0))))
    assert clean.not_determined and spiky.result.not_determined == clean.not_determined
    spikes = spiky.result.input_spikes
    assert [s["time"] for s in spikes] == pytest.approx([run.time[i] for i in at])
    assert spiky.to_json_dict()["input_spikes"] == spikes and "input spikes: 3" in spiky.result.text()
    assert any("3 single-sample spike(s) in steering_wheel_angle" in w for w in spiky.warnings)


def test_three_steering_spikes_no_longer_move_the_estimate(car):
    """On main three spikes moved the polished D1 of a 20 s chirp by 0.83 % (11σ)."""
    from online_id.workflows import estimate

    run = simulate(car, car.truth("track"), duration_s=20.0, rate_hz=200.0, seed=4).run
    a = estimate(run).result
    b = estimate(_with_spikes(run, ((900, 100.0), (2100, 115.0), (3300, 170.0)))).result
    moved = b.parameters.to_vector() / a.parameters.to_vector() - 1
    assert np.all(np.abs(moved) < 0.2 * b.relative_std), dict(zip(PARAMETER_NAMES, moved))
    assert len(b.input_spikes) == 3 and b.to_json_dict()["input_spikes"][0]["channel"] == "steering_wheel_angle"


def test_the_race_logs_three_steering_glitches_are_found_and_nothing_else():
    """The race car's 400 s at 100 Hz: 105°, 116° and 183° for one sample each between neighbours under 15°,
    and no other sample of 400 s of racing (its fastest real steering is 380 deg/s) nor any speed sample."""
    from online_id.io.tracklog import read_track_run
    from online_id.trust.spikes import mend_run
    from tests.conftest import SHARED

    run = read_track_run(SHARED / "realdata" / "revs_250lm" / "revs_250lm_laps_0-400s.csv")
    mended, spikes = mend_run(run)
    assert [round(s.time, 2) for s in spikes] == [57.28, 353.5, 374.86]
    assert [round(np.degrees(s.value)) for s in spikes] == [105, 116, 183]
    assert {s.channel for s in spikes} == {"steering_wheel_angle"}
    assert np.count_nonzero(mended.steering_wheel_angle != run.steering_wheel_angle) == 3
