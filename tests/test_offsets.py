"""Offsets and effects learned online: extra filter states (online_id/filters/augment.py) through the
public API (make_estimator(effects=, offsets=), run_estimator) and the CLI (estimate/fit --effect,
--offsets).

Identification tests simulate the Table 6 car with known offsets or effects plus sensor noise and
require every parameter within the stated tolerance of truth and each offset within 10 %.
"""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

from online_id.cli.main import main
from online_id.diagnosis.diagnose import diagnose_gap
from online_id.effects import parse_effect, parse_effect_to_estimate
from online_id.estimation import make_estimator, run_estimator
from online_id.filters import FilterConfig
from online_id.io.tracklog import write_track_run
from online_id.sim.simulator import simulate
from online_id.stream.samples import samples_from_run
from online_id.vehicle import PARAMETER_NAMES, load_vehicle

#: The issue's acceptance: every parameter within 2 % and each offset within 10 % with offsets on;
#: on a clean run with offsets on, today's accuracy (EKF 0.5 %, UKF 1 %).
OFFSET_RUN_TOLERANCE = 0.02
OFFSET_TOLERANCE = 0.10
CLEAN_TOLERANCE = {"ekf": 0.005, "ukf": 0.01}
LATERAL_OFFSET, YAW_OFFSET, STEERING_OFFSET = 0.3, 0.02, 0.02  # m/s², rad/s, rad

CAR = load_vehicle("haro2008")
TRUTH = CAR.truth("track")


def _run(effects: list[str], duration_s=60.0, seed=1):
    return simulate(CAR, TRUTH, duration_s=duration_s, seed=seed, effects=[parse_effect(t) for t in effects]).run


def _estimate(run, filt, **kw):
    return run_estimator(make_estimator(CAR, filt, **kw), samples_from_run(run))


def _errors(result) -> np.ndarray:
    return result.parameters.to_vector() / TRUTH.to_vector() - 1


def _report(result) -> str:
    return ", ".join(f"{n} {100 * e:+.3f}%" for n, e in zip(PARAMETER_NAMES, _errors(result)))


@pytest.fixture(scope="module")
def offset_run():
    return _run([f"sensor_bias=lateral_acceleration:{LATERAL_OFFSET}", f"sensor_bias=yaw_rate:{YAW_OFFSET}"])


@pytest.mark.parametrize("filt", ["ekf", "ukf"])
def test_offsets_on_recover_the_parameters_and_the_offsets(offset_run, filt):
    res = _estimate(offset_run, filt, offsets=True)
    assert np.all(np.abs(_errors(res)) < OFFSET_RUN_TOLERANCE), _report(res)
    off = res.extra_states["offsets"]
    assert set(off) == {"yaw_rate", "lateral_acceleration", "steering_wheel_angle"}
    assert off["lateral_acceleration"]["value"] == pytest.approx(LATERAL_OFFSET, rel=OFFSET_TOLERANCE)
    assert off["yaw_rate"]["value"] == pytest.approx(YAW_OFFSET, rel=OFFSET_TOLERANCE)
    # the absent steering offset comes out near zero, within 3σ (σ is honest)
    assert abs(off["steering_wheel_angle"]["value"]) < 3 * off["steering_wheel_angle"]["std"] + 1e-4
    assert res.events.get("resets", 0) == 0


@pytest.mark.parametrize("filt", ["ekf", "ukf"])
def test_clean_run_with_offsets_on_keeps_todays_accuracy(filt):
    res = _estimate(_run([]), filt, offsets=True)
    assert np.all(np.abs(_errors(res)) < CLEAN_TOLERANCE[filt]), _report(res)
    for channel, v in res.extra_states["offsets"].items():
        assert abs(v["value"]) < 3 * v["std"], (channel, v)


def test_without_offset_states_the_same_run_is_wrong_and_the_innovations_say_so():
    """The contrast the offsets fix (30 s of the same case): the base filter's parameters go astray."""
    run = _run([f"sensor_bias=lateral_acceleration:{LATERAL_OFFSET}", f"sensor_bias=yaw_rate:{YAW_OFFSET}"],
               duration_s=30.0)
    base = _estimate(run, "ekf")
    learned = _estimate(run, "ekf", offsets=True)
    assert np.abs(_errors(base)).max() > 0.05, _report(base)
    assert np.abs(_errors(learned)).max() < OFFSET_RUN_TOLERANCE, _report(learned)
    for channel in ("yaw_rate", "lateral_acceleration"):
        assert learned.innovation_rms[channel] < 0.5 * base.innovation_rms[channel]


def test_a_steering_offset_enters_like_the_input():
    """δ_true = (δH − b)/i_s: a steering-wheel offset is learned as an input offset, not a sensor one."""
    run = _run([f"sensor_bias=steering_wheel_angle:{STEERING_OFFSET}"], duration_s=30.0)
    res = _estimate(run, "ekf", effects=[parse_effect_to_estimate("sensor_bias:steering_wheel_angle")])
    assert res.extra_states["offsets"]["steering_wheel_angle"]["value"] == pytest.approx(
        STEERING_OFFSET, rel=OFFSET_TOLERANCE)
    assert np.all(np.abs(_errors(res)) < OFFSET_RUN_TOLERANCE), _report(res)


def test_ukf_learns_a_state_coupled_effect_and_an_input_offset_together():
    """The UKF's sigma points carry K·g·φ (accelerometer_gravity) and δ − b/i_s (steering offset)."""
    run = _run(["accelerometer_gravity=1", f"sensor_bias=steering_wheel_angle:{STEERING_OFFSET}"], duration_s=20.0)
    effects = [parse_effect_to_estimate(t) for t in ("accelerometer_gravity", "sensor_bias:steering_wheel_angle")]
    res = _estimate(run, "ukf", effects=effects)
    assert res.extra_states["effects"]["accelerometer_gravity"]["k"]["value"] == pytest.approx(1.0, abs=0.1)
    assert res.extra_states["offsets"]["steering_wheel_angle"]["value"] == pytest.approx(
        STEERING_OFFSET, rel=OFFSET_TOLERANCE)
    assert np.all(np.abs(_errors(res)) < OFFSET_RUN_TOLERANCE), _report(res)


def test_ekf_groups_with_extra_states_give_the_sample_by_sample_result():
    """The EKF's grouped arithmetic with every kind of extra state (output offset, input offset, state
    coupling) equals the per-sample recursion (reading x after each sample forces groups of one)."""
    run = _run(["accelerometer_gravity=1", "sensor_bias=steering_wheel_angle:0.02"], duration_s=1.5)
    effects = [parse_effect_to_estimate(t) for t in ("accelerometer_gravity", "sensor_bias:steering_wheel_angle",
                                                     "sensor_bias:yaw_rate")]
    grouped, single = (make_estimator(CAR, "ekf", effects=effects) for _ in range(2))
    for s in samples_from_run(run):
        grouped.update(s)
        single.update(s)
        single.x  # noqa: B018 -- reading the states works the pending samples now
    assert grouped.events["corrections"] > 50
    np.testing.assert_allclose(grouped.x, single.x, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(grouped.P, single.P, rtol=1e-8, atol=1e-16)


def test_ekf_jacobian_of_the_extra_states_matches_finite_differences():
    """∂(model states after n samples)/∂(extra states): the input offset's column (the output offsets
    do not move the states). Mirrors the parameters' check in test_filters.py."""
    from online_id.filters import EKFEstimator
    from online_id.filters.augment import Augmentation
    from online_id.model.lateral import N_STATES

    effects = [parse_effect_to_estimate("sensor_bias:steering_wheel_angle"), parse_effect_to_estimate(
        "accelerometer_gravity")]
    aug = Augmentation.from_effects(effects, CAR.known)
    cfg = FilterConfig(correct_every=10)
    est = EKFEstimator(CAR, config=cfg, augment=aug)
    x0 = est.x.copy()
    x0[:N_STATES] = [0.1, 0.01, 0.01, 0.05, 0.01, 0.005]
    x0[-2:] = [0.03, 0.5]
    # each step's input between its samples (model/intersample.py): value and derivatives in normalised time
    inputs = [(1e-3, np.array([0.02 * np.sin(k / 5), 0.004 * np.cos(k / 5), -8e-4 * np.sin(k / 5), -1.6e-4]), 22.0)
              for k in range(8)]

    def advance(x):
        e = EKFEstimator(CAR, config=cfg, augment=aug)
        e._set(x.copy(), est.P.copy())
        for dt, w, v in inputs:
            e._propagate(dt, w, v)
        return e.x[:N_STATES].copy(), e

    _, e = advance(x0)
    F = e._F_x
    num = np.empty_like(F)
    for j in range(len(x0)):
        h = 1e-6
        xp, xm = x0.copy(), x0.copy()
        xp[j] += h
        xm[j] -= h
        num[:, j] = (advance(xp)[0] - advance(xm)[0]) / (2 * h)
    assert np.abs(num[:, -2]).max() > 1e-3  # the steering offset moves the states
    assert np.abs(F - num).max() / np.abs(num).max() < 1e-5


def test_the_effect_diagnose_names_can_be_added_to_estimate_and_closes_the_gap(tmp_path, capsys):
    """accelerometer_gravity: diagnose names it; estimate --effect with that name learns k ≈ 1, the
    parameters come right and the lateral-acceleration innovations shrink."""
    run = _run(["accelerometer_gravity=1"], duration_s=20.0)
    d = diagnose_gap(CAR, run, effects=["accelerometer_gravity", "sensor_bias"])
    assert d.verdict == "accelerometer_gravity"
    write_track_run(run, tmp_path / "run.csv")
    outs = {}
    for tag, extra in (("base", []), ("effect", ["--effect", d.verdict])):
        out = tmp_path / f"{tag}.json"
        assert main(["estimate", str(tmp_path / "run.csv"), "--quiet", "--json", str(out), *extra]) == 0
        outs[tag] = json.loads(out.read_text())
    printed = capsys.readouterr().out
    assert "effect accelerometer_gravity k:" in printed
    k = outs["effect"]["effects"]["accelerometer_gravity"]["k"]
    assert k["value"] == pytest.approx(1.0, abs=0.1) and k["unit"] == "-"
    assert set(outs["effect"]["parameters"]) == set(PARAMETER_NAMES)  # "parameters" stays the 8
    err = {tag: max(abs(v) for v in o["relative_error"].values()) for tag, o in outs.items()}
    assert err["effect"] < OFFSET_RUN_TOLERANCE < err["base"], err
    ay = {tag: o["innovation_rms"]["lateral_acceleration"] for tag, o in outs.items()}
    assert ay["effect"] < 0.5 * ay["base"], ay


def test_estimate_offsets_json_and_fit_effect_recover_a_lateral_acceleration_offset(tmp_path, capsys):
    run = _run([f"sensor_bias=lateral_acceleration:{LATERAL_OFFSET}"], duration_s=20.0)
    write_track_run(run, tmp_path / "run.csv")
    out = tmp_path / "est.json"
    assert main(["estimate", str(tmp_path / "run.csv"), "--offsets", "--quiet", "--json", str(out)]) == 0
    est = json.loads(out.read_text())
    lat = est["offsets"]["lateral_acceleration"]
    assert set(lat) == {"value", "std", "unit"} and lat["unit"] == "m/s²"
    assert lat["value"] == pytest.approx(LATERAL_OFFSET, rel=OFFSET_TOLERANCE)
    assert "offset lateral_acceleration:" in capsys.readouterr().out
    out = tmp_path / "fit.json"
    assert main(["fit", str(tmp_path / "run.csv"), "--effect", "sensor_bias:lateral_acceleration", "--quiet",
                 "--generations", "60", "--groups", "4", "--json", str(out)]) == 0
    fit = json.loads(out.read_text())
    bias = fit["effects"]["sensor_bias(lateral_acceleration)"]["bias"]
    assert bias["value"] == pytest.approx(LATERAL_OFFSET, rel=OFFSET_TOLERANCE) and bias["std"] > 0
    assert max(abs(v) for v in fit["relative_error"].values()) < OFFSET_RUN_TOLERANCE


@pytest.mark.parametrize("args, message", [
    (["--effect", "sensor_delay:speed"], "unknown channel 'speed'"),
    (["--effect", "steering_delay:fast"], "a number, got 'fast'"),
    (["--effect", "steering_compliance"], "steering_compliance: no filter form: exactly equivalent"),
    (["--effect", "sensor_bias"], "sensor_bias: no channel given"),
    (["--effect", "sensor_bias:speed"], "unknown channel 'speed'"),
    (["--effect", "warp_drive"], "unknown effect 'warp_drive'"),
    (["--effect", "sensor_bias:yaw_rate", "--effect", "sensor_bias:yaw_rate"], "asked for twice"),
])
def test_an_effect_the_filters_cannot_take_is_a_clear_error(tmp_path, capsys, args, message):
    run = _run([], duration_s=2.0)
    write_track_run(run, tmp_path / "run.csv")
    assert main(["estimate", str(tmp_path / "run.csv"), "--quiet", *args]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1, err


# -- an offset with default options (issue 30) --------------------------------------------------------------
@pytest.mark.parametrize("effect", [f"sensor_bias=lateral_acceleration:{LATERAL_OFFSET}",
                                    f"sensor_bias=yaw_rate:{YAW_OFFSET}"])
def test_an_offset_without_offset_states_ends_in_no_confident_wrong_answer_and_points_to_offsets(effect):
    """Before: about 1,100 resets over 60 s, Mzz 73x, every parameter "informed". Now the filter stops learning
    once its resets come in a burst (held at the prior, with the prior's σ, not informed), says early that
    a_y − V·r shows an offset, and the verdict's first next step is --offsets."""
    run = _run([effect], duration_s=30.0)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = _estimate(run, "ekf")
    said = [str(w.message) for w in caught]
    errors = _errors(res)
    confident_and_wrong = [n for n, e in zip(PARAMETER_NAMES, errors) if res.informed[n] and abs(e) > 0.05]
    assert not confident_and_wrong, (_report(res), res.informed)
    assert np.all(res.relative_std >= 0.05) or np.abs(errors).max() < 0.05, _report(res)  # wide σ or right
    assert res.events.get("resets", 0) <= FilterConfig().diverged_resets, res.events
    assert any("a_y − V·r averages" in m and "--offsets" in m for m in said), said
    c = res.consistency
    assert c["consistent"] is False and any("a_y − V·r" in r for r in c["reasons"]), c["reasons"]
    assert c["next_steps"][0]["add"] == ["--offsets"], c["next_steps"]


def test_the_kinematic_balance_sees_an_offset_and_no_dynamics():
    from online_id.filters.kinematics import MIN_OFFSET_MPS2, KinematicBalance

    clean = _run([], duration_s=30.0)
    for offset, expected in ((0.0, None), (0.3, 0.3), (-0.02 * 22.2, -0.02 * 22.2)):
        k = KinematicBalance()
        dt = np.diff(clean.time, prepend=0.0)
        for h, v, r, ay in zip(dt, clean.speed, clean.yaw_rate, clean.lateral_acceleration + offset):
            k.add(h, v, r, ay)
        found = k.offset()
        if expected is None:
            assert found is None and abs(k.mean) < MIN_OFFSET_MPS2, k.to_dict()
        else:
            assert found == pytest.approx(expected, abs=0.02), k.to_dict()
    assert KinematicBalance().offset() is None  # nothing seen, nothing said
    # a car that spins (V·r far beyond a_y) has no bounded sideslip: nothing is said of an offset
    spin = KinematicBalance()
    for _ in range(1000):
        spin.add(0.01, 22.0, 1.0, 8.0 - 6.3)
    assert spin.spun and spin.offset() is None


def test_no_offset_is_read_into_the_race_car_or_a_clean_run():
    """The real race car at 1.7 g (sideslip, braking, 16-61 m/s) and a clean simulated run: the balance
    a_y − V·r stays within what the dynamics allow."""
    from online_id.filters.kinematics import KinematicBalance
    from online_id.io.tracklog import read_track_run
    from tests.conftest import SHARED

    race_car = read_track_run(SHARED / "realdata" / "revs_250lm" / "revs_250lm_laps_0-400s.csv")
    for run in (race_car, _run([], duration_s=60.0, seed=3)):
        k = KinematicBalance()
        dt = np.diff(run.time, prepend=run.time[0])
        for h, v, r, ay in zip(dt, run.speed, run.yaw_rate, run.lateral_acceleration):
            k.add(h, v, r, ay)
        assert k.offset() is None, (run.source, k.to_dict())
