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


def test_without_a_roll_channel_the_fits_hold_the_roll_parameters():
    """A run without roll_angle and roll_rate cannot inform Mxx, Aro and Kro: every fit of the diagnosis holds them
    where they start (left free, the race car's two-channel fits wandered to stiff roll modes, past 40 min), says
    so (FamilyFit.held), and still fits the others; with a roll channel all 8 are fitted."""
    from online_id.diagnosis.fitting import BlockModel, fit_family
    from online_id.filters.prior import ROLL_PARAMETERS
    from online_id.model.lateral import PARAMETER_NAMES

    run = simulate(CAR, CAR.truth("track"), duration_s=20.0, rate_hz=100.0).run
    start = CAR.truth("track").to_vector() * np.array([1.1, 1.3, 0.95, 1.05, 0.8, 1.2, 1.1, 0.9])
    roll = [PARAMETER_NAMES.index(n) for n in ROLL_PARAMETERS]
    two = BlockModel(CAR, only_run_channels(run, "yaw_rate,lateral_acceleration"))
    fit = fit_family(two, np.arange(two.n_blocks) >= two.first_block, start)
    assert fit.held == ROLL_PARAMETERS and fit.n_params == 5
    np.testing.assert_array_equal(fit.theta[roll], start[roll])
    assert not np.allclose(np.delete(fit.theta, roll), np.delete(start, roll))
    four = BlockModel(CAR, run)
    fit = fit_family(four, np.arange(four.n_blocks) >= four.first_block, start)
    assert fit.held == () and fit.n_params == 8 and not np.any(fit.theta[roll] == start[roll])
