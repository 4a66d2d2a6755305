"""What no effect of the model explains (online_id/diagnosis/kinematics.py): the slow part of v̇_y + V·r − a_y, zero on a
level road whatever the tyres do, g·sin(bank) on a banked one; told with the diagnosis's remaining gap."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from online_id.diagnosis.diagnose import diagnose_gap
from online_id.diagnosis.kinematics import LIMIT_MPS2, kinematics_line, lateral_kinematics
from online_id.effects import parse_effect
from online_id.sim.maneuvers import SpeedProfile
from online_id.sim.simulator import simulate
from online_id.vehicle.loader import load_vehicle

VEHICLE = load_vehicle("haro2008")
THETA = VEHICLE.truth("track")
#: a bank that comes and goes along the run: 0.3 m/s² (1.75°) at its largest, over 20 s
BANK_AMPLITUDE, BANK_PERIOD_S = 0.3, 20.0


def _run(rate_hz, **kw):
    return simulate(VEHICLE, THETA, duration_s=60.0, rate_hz=rate_hz, maneuver="sine", frequency_hz=0.5,
                    amplitude_rad=np.deg2rad(60.0), seed=2, lateral_velocity=True, **kw).run


@pytest.mark.parametrize("rate_hz", [25.0, 100.0])
def test_a_level_road_is_consistent_and_a_banked_one_is_told_with_its_size(rate_hz):
    """The model's own car at 0.5 g with sensor noise: the slow part at the noise, consistent. The same run as the
    sensors of a car on a bank would log it (the accelerometer short of V·r + v̇_y by g·sin(bank); the tyres' answer
    to the bank is left out: what is checked is the kinematics alone): beyond the limit, its RMS within 10 % of the
    bank's (0.3/√2 m/s², less the 3 s mean's 4 % on a 20 s period) and its largest as a bank angle within 15 %."""
    run = _run(rate_hz)
    level = lateral_kinematics(run)
    assert not level["beyond"] and level["left_rms_mps2"] < 0.03, level
    assert level["checked"] and "no input missing" in kinematics_line(level)[0]
    bank = BANK_AMPLITUDE * np.sin(2 * np.pi * run.time / BANK_PERIOD_S)
    banked = lateral_kinematics(replace(run, lateral_acceleration=run.lateral_acceleration - bank))
    assert banked["beyond"] and banked["left_rms_mps2"] > LIMIT_MPS2
    assert banked["left_rms_mps2"] == pytest.approx(BANK_AMPLITUDE / np.sqrt(2) * 0.963, rel=0.1)
    # the 95th percentile of |0.3·sin| is 0.3·sin(0.95·π/2), less the 3 s mean's 4 %
    p95 = np.degrees(np.arcsin(0.963 * BANK_AMPLITUDE * np.sin(0.95 * np.pi / 2) / 9.81))
    assert banked["bank_deg_p95"] == pytest.approx(p95, rel=0.15)
    assert "an input no effect of the model can produce" in kinematics_line(banked)[0]


def test_what_an_effect_of_the_model_explains_is_not_told():
    """An accelerometer reading 3 % high (a roll-tilted or mis-scaled sensor: proportional to a_y), a bias, and an INS
    turned 0.01 rad in yaw on a run that brakes and accelerates (its v_y off by −0.01·V, whose derivative follows
    dV/dt): effects the diagnosis has, so the kinematics stay consistent; a run without lateral velocity has no
    entry."""
    speed = SpeedProfile([(0, 30.0), (15, 18.0), (30, 32.0), (45, 20.0), (60, 30.0)])
    run = _run(100.0, speed_mps=speed, effects=[parse_effect("lateral_velocity_misalignment=0.01")])
    entry = lateral_kinematics(replace(run, lateral_acceleration=1.03 * run.lateral_acceleration + 0.2))
    assert not entry["beyond"] and entry["left_rms_mps2"] < 0.03, entry
    assert entry["coefficients"]["speed_derivative"] == pytest.approx(-np.sin(0.01), abs=0.003)
    assert lateral_kinematics(replace(run, lateral_velocity=None)) is None
    broken = run.lateral_velocity.copy()
    broken[100] = np.nan
    for bad, reason in ((replace(run, lateral_velocity=broken), "not finite"),
                        (replace(run, **{c: getattr(run, c)[:500] for c in run.channels}), "shorter than 6 s")):
        entry = lateral_kinematics(bad)  # no number from garbage, and said so
        assert not entry["checked"] and reason in entry["reason"] and "left_rms_mps2" not in entry
        assert reason in kinematics_line(entry)[0]


def test_the_diagnosis_tells_the_kinematics_with_what_is_left(tmp_path):
    """In the remaining gap of a diagnosis (its JSON's ``remaining_gap.lateral_kinematics``), judged on the held-out
    run: consistent for the model's own car, beyond for the banked one."""
    train, held = _run(100.0), simulate(VEHICLE, THETA, duration_s=30.0, rate_hz=100.0, seed=5,
                                        lateral_velocity=True).run
    d = diagnose_gap(VEHICLE, train, held, effects=["sensor_bias"])
    entry = d.to_json_dict()["remaining_gap"]["lateral_kinematics"]
    assert entry["beyond"] is False and entry["span"] == "held-out run"
    bank = BANK_AMPLITUDE * np.sin(2 * np.pi * held.time / BANK_PERIOD_S)
    d = diagnose_gap(VEHICLE, train, replace(held, lateral_acceleration=held.lateral_acceleration - bank),
                     effects=["sensor_bias"])
    assert d.to_json_dict()["remaining_gap"]["lateral_kinematics"]["beyond"] is True


@pytest.mark.parametrize("step", [10, 4])
def test_an_independent_simulators_car_on_a_level_road_is_consistent(step):
    """CommonRoad's multi-body BMW (its own tyres, sprung and unsprung masses, its whole car's lateral velocity),
    integrated at 250 Hz and logged at 25 and 62.5 Hz: consistent, its slow part a tenth of the limit or less."""
    pytest.importorskip("vehiclemodels", reason="the independent simulator (installed by the test extra)")
    from tests.independent_sim import simulate_mb

    run = simulate_mb(2, "chirp", duration_s=30.0, rate_hz=250.0, lateral_velocity=True)
    entry = lateral_kinematics(replace(run, **{c: getattr(run, c)[::step] for c in run.channels}))
    assert not entry["beyond"] and entry["left_rms_mps2"] < 0.2 * LIMIT_MPS2, entry


def test_the_cli_prints_it_also_when_the_lateral_velocity_is_not_judged(tmp_path, capsys):
    """`diagnose --channels yaw_rate,lateral_acceleration` (README step 4b's way) leaves the lateral velocity out of the
    fits, but the kinematics read the data: the line is printed, on the whole run, saying so; its JSON too."""
    from online_id.cli.main import main
    from online_id.io.tracklog import write_track_run

    run = _run(100.0)
    bank = BANK_AMPLITUDE * np.sin(2 * np.pi * run.time / BANK_PERIOD_S)
    log = tmp_path / "banked.csv"
    write_track_run(replace(run, lateral_acceleration=run.lateral_acceleration - bank), log)
    out = tmp_path / "d.json"
    assert main(["diagnose", str(log), "--vehicle", "haro2008", "--effects", "sensor_bias",
                 "--channels", "yaw_rate,lateral_acceleration", "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    line = next(x for x in printed.splitlines() if x.startswith("v̇_y + V·r − a_y"))
    assert "whole run, lateral_velocity not among the judged channels" in line and "beyond 0.1 m/s²" in line
    import json
    entry = json.loads(out.read_text())["remaining_gap"]["lateral_kinematics"]
    assert entry["judged"] is False and entry["beyond"] is True
