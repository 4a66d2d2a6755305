"""diagnose --channels (issue 38): the measured channels the model is judged on, the others left out of every fit
(a race car's INS lateral velocity that the model does not fit, say)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from online_id.cli.main import main
from online_id.errors import OnlineIdError
from online_id.io.tracklog import write_track_run
from online_id.sim.simulator import simulate
from online_id.vehicle import load_vehicle
from online_id.workflows.inputs import only_run_channels

CAR = load_vehicle("haro2008")


def test_only_run_channels_leaves_the_others_out_and_refuses_what_the_run_lacks():
    run = simulate(CAR, CAR.truth("track"), duration_s=2.0, rate_hz=100.0, lateral_velocity=True).run
    two = only_run_channels(run, "yaw_rate,lateral_acceleration")
    assert two.channels == ["time", "steering_wheel_angle", "speed", "yaw_rate", "lateral_acceleration"]
    np.testing.assert_array_equal(two.yaw_rate, run.yaw_rate)
    with pytest.raises(OnlineIdError, match="unknown channel 'sideslip'"):
        only_run_channels(run, "yaw_rate,sideslip")
    with pytest.raises(OnlineIdError, match="lateral_velocity is not in"):
        only_run_channels(only_run_channels(run, "yaw_rate"), "lateral_velocity")


def test_diagnose_channels_judges_the_model_on_those_alone(tmp_path, capsys):
    run = simulate(CAR, CAR.truth("track"), duration_s=20.0, rate_hz=100.0, lateral_velocity=True).run
    log = write_track_run(run, tmp_path / "run.csv")
    out = {}
    for name, extra in (("all", []), ("four", ["--channels", "yaw_rate,roll_angle,roll_rate,lateral_acceleration"])):
        path = tmp_path / f"{name}.json"
        assert main(["diagnose", str(log), "--effects", "sensor_bias", "--quiet", "--json", str(path), *extra]) == 0
        out[name] = json.loads(path.read_text())
    capsys.readouterr()
    assert "lateral_velocity" in json.dumps(out["all"]["gap"])
    assert "lateral_velocity" not in json.dumps(out["four"]["gap"])
