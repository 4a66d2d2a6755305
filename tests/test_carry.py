"""From diagnosis to estimate (issue 24 item 4), and the polish with tyres (item 3).

``diagnose --json`` holds ``"carry"``: the named effects as ``--effect`` values from their fitted values;
``--effects-from DIAG.json`` takes them into ``estimate``, ``fit``, ``listen``, ``batch`` and the API. The
default polish of ``estimate --effect tire_saturation`` polishes μ with the 8 through the filters' model.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from online_id import api
from online_id.batchfit.polish import polish
from online_id.cli.main import main
from online_id.diagnosis.carry import carry_flags, effects_from_diagnosis
from online_id.effects import parse_effect, parse_effect_to_estimate
from online_id.errors import OnlineIdError
from online_id.io.tracklog import write_track_run
from online_id.sim.simulator import simulate
from online_id.vehicle import load_vehicle
from online_id.vehicle.parameters import PARAMETER_NAMES

CAR = load_vehicle("haro2008")
THETA = CAR.truth("track").to_vector()
MU = 0.8


@pytest.fixture(scope="module")
def tanh_run():
    """20 s of the built-in chirp at 60° and 80 km/h with tanh tyres of μ 0.8: peak |a_y| about 0.9 g."""
    return simulate(CAR, CAR.truth("track"), duration_s=20, seed=4, speed_mps=80 / 3.6,
                    amplitude_rad=np.deg2rad(60), effects=[parse_effect(f"tire_saturation={MU}")]).run


def _diagnosis_json(path, effects):
    """A diagnosis file as ``diagnose --json`` writes its carry (the other keys as a diagnosis has them)."""
    carry = carry_flags(effects, CAR.known) if effects else None
    path.write_text(json.dumps({"verdict": effects[0].name if effects else None, "effects": [], "carry": carry}))
    return path


def test_carry_splits_what_the_filters_carry_from_what_only_the_fit_does():
    tyre = parse_effect_to_estimate("tire_saturation:1.02")
    delay = parse_effect_to_estimate("sensor_delay:yaw_rate:0.025")
    compliance = parse_effect_to_estimate("steering_compliance:0.1")
    carry = carry_flags([tyre, delay, compliance], CAR.known)
    assert carry["online"] == ["tire_saturation:1.02", "sensor_delay:yaw_rate:0.025"]
    assert carry["fit"] == ["tire_saturation:1.02", "sensor_delay:yaw_rate:0.025", "steering_compliance:0.1"]
    assert carry["not_online"] == ["steering_compliance"]
    assert carry["estimate_flags"] == "--effect tire_saturation:1.02 --effect sensor_delay:yaw_rate:0.025"
    # what is printed parses back to the same effects, from the fitted values
    back = [parse_effect_to_estimate(s) for s in carry["fit"]]
    assert [(e.label, e.values) for e in back] == [(e.label, e.values) for e in (tyre, delay, compliance)]


@pytest.mark.parametrize("text, message", [
    ("{not json", "not JSON (line 1"),
    ('{"parameters": {}}', "not the JSON of 'online-id diagnose --json'"),
    ('{"verdict": "x", "carry": {"online": 3}}', "has no list 'online'"),
    ('{"verdict": "x", "carry": {"online": ["warp_drive:1"]}}', "unknown effect 'warp_drive'"),
])
def test_a_file_that_is_not_a_diagnosis_is_one_clear_error(tmp_path, text, message):
    path = tmp_path / "d.json"
    path.write_text(text)
    with pytest.raises(OnlineIdError, match="--effects-from .*d.json") as err:
        effects_from_diagnosis(path, online=True)
    assert message in str(err.value)
    assert main(["estimate", "--effects-from", str(path)]) == 2  # a one-line error before any work


def test_a_diagnosis_without_a_verdict_carries_nothing_and_says_so(tmp_path):
    said = []
    assert effects_from_diagnosis(_diagnosis_json(tmp_path / "d.json", []), online=True, warn=said.append) == []
    assert "named no effect" in said[0]


def test_estimate_effects_from_learns_mu_over_the_whole_envelope_and_polishes_it(tanh_run, tmp_path, capsys):
    """The diagnosis's μ (a rough 1.0) starts the filter; the default polish fits μ with the 8. The compliance it
    also named has no filter form: a warning, and left out."""
    write_track_run(tanh_run, tmp_path / "run.csv")
    diag = _diagnosis_json(tmp_path / "d.json", [parse_effect_to_estimate("tire_saturation:1.0"),
                                                 parse_effect_to_estimate("steering_compliance:0.01")])
    out = tmp_path / "e.json"
    assert main(["estimate", str(tmp_path / "run.csv"), "--effects-from", str(diag), "--json", str(out),
                 "--quiet"]) == 0
    err = capsys.readouterr().err
    assert "steering_compliance has no filter form yet" in err
    d = json.loads(out.read_text())
    mu = d["effects"]["tire_saturation"]["mu"]
    assert mu["value"] == pytest.approx(MU, rel=0.01) and abs(mu["value"] - MU) < 4 * mu["std"]
    assert "error" not in d["polish"] and d["polish"]["effects"]["tire_saturation"]["mu"]["value"] == mu["value"]
    assert d["online"]["effects"]["tire_saturation"]["mu"]["value"] == pytest.approx(MU, rel=0.02)  # the filter's
    for n in PARAMETER_NAMES:
        p = d["parameters"][n]
        assert abs(p["value"] / THETA[PARAMETER_NAMES.index(n)] - 1) < 0.01, n
    assert d["consistency"]["consistent"] is True


def test_the_polish_with_tyres_has_the_exact_jacobian_and_recovers_mu(tanh_run):
    """From 10 % off on every parameter and μ 1.2: back to the truth within 1 % (the noise allows far less)."""
    start = THETA * np.array([1.1, 0.9, 1.1, 0.9, 1.1, 0.9, 1.1, 0.9])
    p = polish(CAR, tanh_run, start, {"yaw_rate": 0.004, "roll_angle": 0.001, "lateral_acceleration": 0.05},
               burn_in_s=1.0, effects=[parse_effect_to_estimate("tire_saturation:1.2")])
    assert p.success and not p.at_bound
    assert np.max(np.abs(p.theta / THETA - 1)) < 0.01, p.theta / THETA
    mu = p.effects["tire_saturation"]["mu"]
    assert mu["value"] == pytest.approx(MU, rel=0.01) and mu["std"] > 0


def test_fit_and_the_api_take_effects_from_a_diagnosis(tanh_run, tmp_path):
    diag = _diagnosis_json(tmp_path / "d.json", [parse_effect_to_estimate("tire_saturation:1.0")])
    est = api.estimate(tanh_run, effects_from=diag, polish=False)
    mu = est.result.extra_states["effects"]["tire_saturation"]["mu"]
    assert mu["value"] == pytest.approx(MU, rel=0.02)
    with pytest.raises(OnlineIdError, match="no filter form"):
        api.estimate(tanh_run, effects=["steering_compliance"])


def test_listen_and_batch_take_effect_flags_and_refuse_a_bad_one_before_any_work(tmp_path, capsys):
    """listen: the flag is checked before the bus is opened (no bus exists here: an error about it would
    mean the check came too late); batch: before any log is read."""
    assert main(["listen", "--interface", "no_such_interface", "--channel", "none",
                 "--effect", "steering_compliance"]) == 2
    assert "no filter form" in capsys.readouterr().err
    assert main(["batch", str(tmp_path / "missing.csv"), "--out", str(tmp_path / "o"), "--workers", "0",
                 "--effect", "warp_drive"]) == 2
    assert "unknown effect 'warp_drive'" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_batch_carries_tire_saturation_into_each_log(tanh_run, tmp_path):
    write_track_run(tanh_run, tmp_path / "run.csv")
    out = tmp_path / "o"
    assert main(["batch", str(tmp_path / "run.csv"), "--out", str(out), "--workers", "0", "--quiet",
                 "--effect", "tire_saturation"]) == 0
    doc = json.loads(next(p for p in out.glob("*.json")).read_text())
    assert doc["options"]["effects"] == ["tire_saturation:1.5"]
    assert doc["estimate"]["effects"]["tire_saturation"]["mu"]["value"] == pytest.approx(MU, rel=0.01)


def test_a_polish_that_cannot_finish_in_time_says_so_before_the_work(tanh_run, monkeypatch):
    """A pass over 20 s at 1 kHz costs about 0.3 s: with a 0.1 s budget the polish refuses before its first pass,
    saying why (the race car's polish from the filter's b2 of 1.5 cm at 61 m/s ran for minutes)."""
    from online_id.model import tyres

    def no_pass(*args):
        raise AssertionError("a pass was started")

    monkeypatch.setattr(tyres, "simulate_blocks", no_pass)
    with pytest.raises(OnlineIdError, match=r"would run past its 0.1 s: .*1 RK4 sub-steps a sample; shortest relaxation"
                                            r" length 640 mm"):
        polish(CAR, tanh_run, THETA, {"yaw_rate": 0.004}, effects=[parse_effect_to_estimate("tire_saturation")],
               max_wall_s=0.1)


def test_a_combination_of_the_tyres_and_a_delay_is_carried_into_the_tyre_model_filter():
    """Issue 25 item 4: a diagnosis whose combination is tire_saturation + sensor_delay(yaw_rate) (both with a
    filter form) carries both; the tyre model's filter learns μ and τ together (its ẏ by backward
    differences). 12 s at 500 Hz of the 0.9 g chirp with μ 0.8 and the gyro 25 ms late; about 20 s."""
    run = simulate(CAR, CAR.truth("track"), duration_s=12, rate_hz=500, seed=6, speed_mps=80 / 3.6,
                   amplitude_rad=np.deg2rad(60),
                   effects=[parse_effect(f"tire_saturation={MU}"), parse_effect("sensor_delay=yaw_rate:0.025")]).run
    named = [parse_effect_to_estimate("sensor_delay:yaw_rate:0.02"), parse_effect_to_estimate("tire_saturation:1.0")]
    carry = carry_flags(named, CAR.known)
    assert carry["online"] == ["sensor_delay:yaw_rate:0.02", "tire_saturation:1"] and not carry["not_online"]
    est = api.estimate(run, effects_from=_CarryOnly(carry), polish=False).result
    mu = est.extra_states["effects"]["tire_saturation"]["mu"]["value"]
    tau = est.extra_states["effects"]["sensor_delay(yaw_rate)"]["delay_s"]["value"]
    errors = est.parameters.to_vector() / THETA - 1
    print(f"μ {mu:.4f}, τ {1e3 * tau:.2f} ms, largest parameter error {100 * np.abs(errors).max():.2f} %")
    assert mu == pytest.approx(MU, rel=0.02) and tau == pytest.approx(0.025, rel=0.1)
    assert np.abs(errors).max() < 0.02


class _CarryOnly:
    """A diagnosis as the API passes one (``result.carry``), without running one."""

    def __init__(self, carry):
        self.result = type("R", (), {"carry": carry})()
