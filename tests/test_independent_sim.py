"""An independent simulator (CommonRoad's multibody model, three cars) against online-id.

What must hold on a car online-id did not write: its inputs pass the plausibility checks (it is a
real car model in ISO signs), and EKF and UKF agree within 3 combined σ on every parameter, or the
run is flagged inconsistent with a reason (``result.consistency``, built by online_id/trust/consistency.py).
"""

from __future__ import annotations

import functools

import numpy as np
import pytest

pytest.importorskip("vehiclemodels", reason="the test extra commonroad-vehicle-models is not installed")

from online_id.estimation import EstimationResult, make_estimator, run_estimator  # noqa: E402
from online_id.stream.samples import samples_from_run  # noqa: E402
from online_id.trust.plausibility import judge_run  # noqa: E402
from online_id.vehicle.parameters import PARAMETER_NAMES  # noqa: E402
from tests.independent_sim import nominal_parameters, simulate_mb, vehicle_for  # noqa: E402

#: (car, manoeuvre, km/h): three cars, three manoeuvres, 60-80 km/h. 20 s at 250 Hz each (RK4 at
#: the sample period; 500 Hz changes peak a_y by under 1 %).
CASES = [(1, "chirp", 80), (2, "chirp", 60), (3, "steps", 70), (2, "sines", 80)]
DURATION_S, RATE_HZ = 20.0, 250.0
#: EKF and UKF agree when every parameter's difference is within this many combined σ.
AGREEMENT_SIGMAS = 3.0


@functools.cache
def mb_run(car, maneuver, kmh):
    """Simulated once per session."""
    return simulate_mb(car, maneuver, speed_kmh=kmh, duration_s=DURATION_S, rate_hz=RATE_HZ, seed=car)


@functools.cache
def estimates(car, maneuver, kmh):
    run, vehicle = mb_run(car, maneuver, kmh), vehicle_for(car)
    return {f: run_estimator(make_estimator(vehicle, f), samples_from_run(run)) for f in ("ekf", "ukf")}


def disagreement(ekf, ukf) -> np.ndarray:
    """|EKF − UKF| per parameter in combined σ, shape (8,)."""
    return np.abs(ekf.parameters.to_vector() - ukf.parameters.to_vector()) / np.hypot(ekf.std, ukf.std)


@pytest.mark.parametrize("case", CASES, ids=lambda c: f"car{c[0]}-{c[1]}-{c[2]}")
def test_its_runs_pass_the_plausibility_checks(case):
    run = mb_run(*case)
    report = judge_run(run, vehicle_for(case[0]))
    assert not report.failures, [r.message for r in report.failures]
    for check in ("ay_slope", "yaw_sign", "steering_gain", "roll"):
        assert report.by_check(check).status == "ok", report.by_check(check).message
    assert 0.9 < report.by_check("ay_slope").value < 1.1


@pytest.mark.parametrize("case", CASES, ids=lambda c: f"car{c[0]}-{c[1]}-{c[2]}")
def test_ekf_and_ukf_agree_or_the_run_is_flagged_with_a_reason(case):
    res = estimates(*case)
    z = disagreement(res["ekf"], res["ukf"])
    nominal = nominal_parameters(case[0]).parameters.to_vector()
    print(f"\n{case}: EKF-UKF |z| " + " ".join(f"{n} {v:.1f}" for n, v in zip(PARAMETER_NAMES, z)))
    for f, r in res.items():
        print(f"  {f}: " + " ".join(f"{n} {v / nom:.2f}x" for n, v, nom in
                                    zip(PARAMETER_NAMES, r.parameters.to_vector(), nominal)) + "  (of nominal)")
    if np.all(z <= AGREEMENT_SIGMAS):
        return
    # They disagree: then the run must say so, with its reason (online_id/trust/consistency.py, helper i14a).
    if not hasattr(EstimationResult, "consistency") and getattr(res["ekf"], "consistency", None) is None:
        pytest.xfail(f"EKF and UKF disagree by up to {z.max():.1f} combined σ; the verdict that must flag it"
                     " (EstimationResult.consistency) is not in this code yet")
    for f, r in res.items():
        verdict = getattr(r, "consistency", None)
        assert verdict is not None, (f"EKF and UKF disagree by up to {z.max():.1f} combined σ"
                                     f" ({PARAMETER_NAMES[int(z.argmax())]}) and {f} gives no consistency verdict")
        assert verdict["consistent"] is False and verdict["reasons"], (f, verdict)


@pytest.mark.parametrize("case", [(2, "chirp", 60)], ids=lambda c: f"car{c[0]}-{c[1]}-{c[2]}")
def test_with_its_lateral_velocity_ekf_and_ukf_agree_or_the_run_is_flagged(case):
    """The MB car's lateral velocity at its centre of gravity (issue 38) logged too: the filters take it, and
    agree or say why not, with its innovations among the evidence (measured: EKF-UKF worst 8.1 combined σ
    without it, 5.2 with it; both flagged, innovations 6-64× their size: that car is not Haro's model)."""
    car, maneuver, kmh = case
    run = simulate_mb(car, maneuver, speed_kmh=kmh, duration_s=DURATION_S, rate_hz=RATE_HZ, seed=car,
                      lateral_velocity=True)
    res = {f: run_estimator(make_estimator(vehicle_for(car), f), samples_from_run(run)) for f in ("ekf", "ukf")}
    z = disagreement(res["ekf"], res["ukf"])
    print(f"\n{case} with lateral_velocity: EKF-UKF |z| "
          + " ".join(f"{n} {v:.1f}" for n, v in zip(PARAMETER_NAMES, z)))
    for f, r in res.items():
        assert "lateral_velocity" in r.consistency["innovations"]["channels"], f
        if not np.all(z <= AGREEMENT_SIGMAS):
            assert r.consistency["consistent"] is False and r.consistency["reasons"], (f, r.consistency)


def test_the_vehicle_files_come_from_the_parameter_files():
    for car, (mass, l1) in {1: (1225.89, 0.884), 2: (1093.30, 1.156), 3: (1478.90, 1.151)}.items():
        v = vehicle_for(car)
        assert v.known.M == pytest.approx(mass, abs=0.01) and v.known.l1 == pytest.approx(l1, abs=1e-3)
        nominal = nominal_parameters(car).parameters
        assert 0.5 < nominal.Mzz / (v.known.M * v.known.l1 * v.known.l2) < 1.5  # a car's dynamic index
        assert 0.1 < nominal.b1 < 2.0 and 0.1 < nominal.b2 < 2.0


@pytest.mark.parametrize("effect", ["tire_saturation", "tire_saturation_axles"])
def test_past_the_linear_range_with_the_tyre_model_agree_or_flag_and_mu_is_plausible(effect):
    """CommonRoad's car 1 (Pacejka tyres, combined slip, load transfer) at about 0.95 g with
    ``--effect tire_saturation`` (one μ) or ``tire_saturation_axles``: the filters learn from at least 90 % of the
    samples (the linear filters' 0.5 g gate would leave a quarter out), every μ comes out as a tyre's (0.7-1.6), and
    EKF and UKF agree within 3 combined σ (μ included) or both runs are flagged, with the innovations as evidence.
    Measured 2026-11-25 on these 20 s: one μ 1.13 (EKF) and 1.18 (UKF); per axle 1.28/1.04 and 1.36/1.03 (the MB
    car's limit is the rear's); no sample left out; they disagree (Mxx, b1 by 9-26 combined σ, D1 and D2 by 3-5)
    and both say INCONSISTENT: innovations 70-390× their size and not white (the MB car's roll, load transfer and
    combined slip are not the model's). About 35 s per effect."""
    from online_id.effects import parse_effect_to_estimate

    run = simulate_mb(1, "chirp", speed_kmh=80, duration_s=DURATION_S, rate_hz=RATE_HZ, amplitude_deg=60, seed=1)
    assert np.max(np.abs(run.lateral_acceleration)) > 0.85 * 9.81
    vehicle = vehicle_for(1)
    res = {f: run_estimator(make_estimator(vehicle, f, effects=[parse_effect_to_estimate(effect)]),
                            samples_from_run(run)) for f in ("ekf", "ukf")}
    mus = {}
    for f, r in res.items():
        mus[f] = r.extra_states["effects"][effect]
        left_out = r.events.get("outside_model_range", 0) + r.events.get("outside_linear_range", 0)
        print(f"{f}: μ {mus[f]}, {100 * left_out / r.samples:.1f} % left out, {r.consistency['reasons'][:2]}")
        assert all(0.7 < m["value"] < 1.6 for m in mus[f].values()), (f, mus[f])
        assert left_out < 0.1 * r.samples
    z = disagreement(res["ekf"], res["ukf"])
    z_mu = [abs(mus["ekf"][k]["value"] - mus["ukf"][k]["value"]) / np.hypot(mus["ekf"][k]["std"], mus["ukf"][k]["std"])
            for k in mus["ekf"]]
    if np.all(z <= AGREEMENT_SIGMAS) and max(z_mu) <= AGREEMENT_SIGMAS:
        return
    for f, r in res.items():
        assert r.consistency["consistent"] is False, (f, z, z_mu)
        assert any(reason.startswith("innovations") for reason in r.consistency["reasons"]), r.consistency["reasons"]


#: Issue 25: the hidden delay on the independent car's gyro [s], and the acceptance's bound on the carried estimate.
HIDDEN_YAW_DELAY_S, NOMINAL_TOLERANCE = 0.025, 0.10


def test_a_hidden_yaw_rate_delay_at_0_9_g_is_diagnosed_and_carried_or_the_run_is_flagged():
    """CommonRoad's car 1 at about 0.9 g (the 0.2-4 Hz chirp at 56°, 80 km/h, 20 s at 250 Hz) with its yaw rate
    logged 25 ms late: ``diagnose`` (both delays as candidates), then ``estimate --effects-from`` the diagnosis.
    The carried estimate lands within 10 % of the car's nominal mapping, or the run is flagged INCONSISTENT
    with its reasons. Measured 2026-11-26: the MB car is not Haro's model even without a delay (the filters'
    innovations 16-73× their size at 0.44 g, Mxx 0.01-0.65× nominal). Here, with tire_saturation among the
    candidates too (150 s more, left out below for time), the diagnosis named sensor_delay on the lateral
    acceleration (26 ms, −15 % held out; tire_saturation −8 % alone at μ 20, its bound) rather than the gyro;
    carried, the filter put that delay at −0.3 ms, the 8 at 0.15-3.2× nominal, flagged INCONSISTENT
    (innovations 88-812× their size). On 40 s, the filters carrying tire_saturation and sensor_delay:yaw_rate
    found τ 0.9 ms with the hidden delay and 1.2 ms without it (b1 3.6× nominal took the lag). About 45 s."""
    from online_id.workflows import diagnose, estimate
    from online_id.workflows.inputs import effects_of

    run = simulate_mb(1, "chirp", speed_kmh=80, duration_s=DURATION_S, rate_hz=RATE_HZ, amplitude_deg=56, seed=2)
    assert np.max(np.abs(run.lateral_acceleration)) > 0.85 * 9.81
    t = run.time - run.time[0]
    run.yaw_rate = np.interp(t - HIDDEN_YAW_DELAY_S, t, run.yaw_rate, left=0.0)
    vehicle = vehicle_for(1)
    diag = diagnose(run, vehicle=vehicle, effects=["sensor_delay", "steering_delay"], allow_implausible="all")
    d = diag.result
    print({c.fit.label: (round(c.reduction, 3), c.significant, c.fit.effects[0].values) for c in d.candidates},
          "verdict", d.verdict, "carry", d.carry)
    est = estimate(run, vehicle=vehicle, effects_from=diag, allow_implausible="all").result
    nominal = nominal_parameters(1).parameters.to_vector()
    ratio = est.parameters.to_vector() / nominal
    print("carried:", " ".join(f"{n} {r:.2f}x" for n, r in zip(PARAMETER_NAMES, ratio)), est.extra_states,
          est.consistency["reasons"][:2])
    if d.carry:  # what the diagnosis named is what the filter carried
        labels = {e.label for e in effects_of(effects_from=diag, online=True)}
        assert set(est.extra_states.get("effects", {})) == labels
    if np.all(np.abs(ratio - 1) <= NOMINAL_TOLERANCE):
        return
    assert est.consistency["consistent"] is False and est.consistency["reasons"], est.consistency
