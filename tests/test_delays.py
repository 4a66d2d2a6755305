"""Issue 25: delays carried online. A channel logged late (``sensor_delay``) and a car that steers late
(``steering_delay``), simulated with known parameters and noise, then diagnosed and estimated: every parameter
within 1 %, the delay within 10 %.

Costs (measured on the shared 2-core machine under load): each estimate of a 30 s run at 500 Hz 10-15 s
(the filter and its polish), the diagnosis of the steering delay 60-120 s (without the tire_saturation
candidate, whose full-rate fits would take several minutes more and which does not compete on a linear car).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from online_id.cli.main import main
from online_id.effects import parse_effect
from online_id.io.tracklog import write_track_run
from online_id.sim.simulator import simulate
from online_id.vehicle import load_vehicle
from online_id.vehicle.parameters import PARAMETER_NAMES
from online_id.workflows import diagnose, estimate

CAR = load_vehicle("haro2008")
THETA = CAR.truth("track").to_vector()
#: The acceptance's bounds: every parameter within 1 %, the delay within 10 %.
PARAMETER_TOLERANCE, DELAY_TOLERANCE = 0.01, 0.10
DURATION_S, RATE_HZ = 30.0, 500.0
YAW_DELAY, STEERING_DELAY = 0.025, 0.060


def _run(effect: str, seed: int):
    return simulate(CAR, CAR.truth("track"), duration_s=DURATION_S, rate_hz=RATE_HZ, seed=seed,
                    effects=[parse_effect(effect)]).run


def _errors(values) -> dict[str, float]:
    return {n: float(v / t - 1) for n, v, t in zip(PARAMETER_NAMES, values, THETA)}


def test_a_yaw_rate_delay_is_learned_online():
    """``estimate --effect sensor_delay:yaw_rate`` on a run whose gyro is logged 25 ms late: the filter alone
    finds τ within 10 %, and the estimate (filter, then polish) every parameter within 1 %. Without the
    effect the same filter is pulled off: the delay hides in Mzz (the bound's correlation is −0.82)."""
    run = _run(f"sensor_delay=yaw_rate:{YAW_DELAY}", seed=3)
    est = estimate(run, vehicle=CAR, effects=["sensor_delay:yaw_rate"]).result
    errors = _errors(est.parameters.to_vector())
    tau = est.extra_states["effects"]["sensor_delay(yaw_rate)"]["delay_s"]
    online_tau = est.online["effects"]["sensor_delay(yaw_rate)"]["delay_s"]["value"]
    print({n: f"{100 * e:+.3f} %" for n, e in errors.items()}, tau, "filter alone:", online_tau)
    assert max(abs(e) for e in errors.values()) < PARAMETER_TOLERANCE, errors
    assert abs(tau["value"] / YAW_DELAY - 1) < DELAY_TOLERANCE and tau["std"] > 0
    assert abs(online_tau / YAW_DELAY - 1) < DELAY_TOLERANCE
    base = estimate(run, vehicle=CAR, polish=False).result
    assert abs(_errors(base.parameters.to_vector())["Mzz"]) > 5 * abs(errors["Mzz"])


@pytest.fixture(scope="module")
def steering_delayed(tmp_path_factory):
    path = tmp_path_factory.mktemp("steering") / "run.csv"
    run = _run(f"steering_delay={STEERING_DELAY}", seed=5)
    write_track_run(run, path)
    return run, path


@pytest.fixture(scope="module")
def steering_diagnosis(steering_delayed):
    run, path = steering_delayed
    names = ["accelerometer_gravity", "sensor_delay", "steering_delay", "sensor_bias", "steering_compliance"]
    diag = diagnose(run, vehicle=CAR, effects=names)
    out = path.with_name("diag.json")
    diag.to_json(out)
    return diag.result, out


def test_the_diagnosis_names_a_steering_delay(steering_diagnosis):
    """Before this effect existed the diagnosis named sensor_delay on one channel (16 % on held-out data);
    now steering_delay, with at least half the held-out gap gone, τ within 10 %, and carried online."""
    d, _ = steering_diagnosis
    print({c.fit.label: (round(c.reduction, 3), c.significant) for c in d.candidates})
    assert d.verdict == "steering_delay"
    best = d.candidates[0]
    assert best.name == "steering_delay" and best.reduction >= 0.5
    assert abs(best.fit.effects[0].values["delay_s"] / STEERING_DELAY - 1) < DELAY_TOLERANCE
    others = [c for c in d.candidates if c.name == "sensor_delay"]
    assert others and others[0].reduction < best.reduction
    assert [s.split(":")[0] for s in d.carry["online"]] == ["steering_delay"]


def test_estimate_learns_a_steering_delay(steering_delayed, tmp_path, capsys):
    """``estimate --effect steering_delay`` (the CLI, its JSON and its printed line)."""
    _, path = steering_delayed
    out = tmp_path / "est.json"
    assert main(["estimate", str(path), "--effect", "steering_delay", "--json", str(out), "--quiet"]) == 0
    assert "effect steering_delay delay_s:" in capsys.readouterr().out
    d = json.loads(out.read_text())
    errors = {n: d["parameters"][n]["value"] / THETA[i] - 1 for i, n in enumerate(PARAMETER_NAMES)}
    tau = d["effects"]["steering_delay"]["delay_s"]
    print({n: f"{100 * e:+.3f} %" for n, e in errors.items()}, tau, "filter alone:", d["online"]["effects"])
    assert max(abs(e) for e in errors.values()) < PARAMETER_TOLERANCE, errors
    assert abs(tau["value"] / STEERING_DELAY - 1) < DELAY_TOLERANCE
    assert abs(d["online"]["effects"]["steering_delay"]["delay_s"]["value"] / STEERING_DELAY - 1) < DELAY_TOLERANCE


def test_estimate_effects_from_carries_the_diagnosed_steering_delay(steering_delayed, steering_diagnosis):
    """``--effects-from DIAG.json``: the filter starts at the diagnosis's τ, and with it the filter alone lands
    within 2 % on every parameter but b1, which trades against τ, within 3σ and 5 % (from the default start, b1
    is still 16 % off after 30 s: τ and b1 are correlated −0.96 in the bound, docs/guide/gap-diagnosis.md)."""
    run, _ = steering_delayed
    _, diag_path = steering_diagnosis
    est = estimate(run, vehicle=CAR, effects_from=str(diag_path), polish=False).result
    errors = _errors(est.parameters.to_vector())
    z = (est.parameters.to_vector() - THETA) / est.std
    tau = est.extra_states["effects"]["steering_delay"]["delay_s"]
    print({n: f"{100 * e:+.3f} % ({s:+.1f}σ)" for (n, e), s in zip(errors.items(), z)}, tau)
    # within 2 %, or (b1, which trades against τ) within 3σ: measured 2026-11-27 b1 +3.3 % beside τ −0.7 %
    assert all(abs(e) < 0.02 or abs(s) < 3 for e, s in zip(errors.values(), z)), errors
    assert max(abs(e) for e in errors.values()) < 0.05, errors
    assert abs(tau["value"] / STEERING_DELAY - 1) < DELAY_TOLERANCE


def test_simulate_makes_a_steering_delay_with_an_actuator_lag(tmp_path):
    """``simulate --effect steering_delay=SECONDS:LAG_S``: the logged steering leads what the car steers by,
    and the run says what it was made with."""
    out = tmp_path / "lag.csv"
    assert main(["simulate", "--out", str(out), "--duration", "4", "--rate", "200", "--no-noise",
                 "--effect", "steering_delay=0.04:0.02"]) == 0
    meta = json.loads(out.with_suffix(".truth.json").read_text())
    assert meta["effects"] == [{"name": "steering_delay", "delay_s": 0.04, "lag_s": 0.02}]
    e = parse_effect("steering_delay=0.04:0.02")
    t = np.arange(0, 4, 0.005)
    u = np.sin(2 * np.pi * 1.0 * t)
    seen = e.car_steering(u, 0.005)
    # a 1 Hz sine through 40 ms and a 20 ms lag: phase 2π·0.04 + atan(2π·0.02), gain 1/√(1 + (2π·0.02)²)
    w = 2 * np.pi
    expected = np.sin(w * t - w * 0.04 - np.arctan(w * 0.02)) / np.hypot(1, w * 0.02)
    assert np.abs(seen - expected)[t > 1.0].max() < 0.02


def test_fit_learns_a_steering_delay(steering_delayed, tmp_path):
    """``fit --effect steering_delay`` (the GA on the 8, the polish and covariance with τ): 5 s of CPU."""
    _, path = steering_delayed
    out = tmp_path / "fit.json"
    assert main(["fit", str(path), "--effect", "steering_delay", "--generations", "60", "--groups", "4",
                 "--json", str(out), "--quiet"]) == 0
    d = json.loads(out.read_text())
    tau = d["effects"]["steering_delay"]["delay_s"]
    print(d["relative_error"], tau)
    assert max(abs(e) for e in d["relative_error"].values()) < PARAMETER_TOLERANCE
    assert abs(tau["value"] / STEERING_DELAY - 1) < DELAY_TOLERANCE and tau["std"] > 0
