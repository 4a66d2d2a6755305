"""Load sensitivity and downforce (issue 38): each axle's whole tyre curve follows its load, less than linearly.

``load_sensitivity`` scales each axle's static tanh curve by k·s, k = (Fz/Fz⁰)^p with the loads braking and
traction move and s the friction ellipse's share left by the axle's longitudinal force; ``downforce`` adds
c·Fz⁰·(V/50 m/s)² to the loads. The acceptance-style run is made by tests/test_load_transfer.py's own equations
(scipy's DOP853 to 1e-10, not online_id's simulator) with that law: the diagnosis must name it on a run it did not
fit, with p, and the filters carrying it must get the 8 within 3 % and μ within 5 %, consistent.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from online_id.effects import EFFECTS, parse_effect
from online_id.errors import OnlineIdError
from online_id.model import tyres
from online_id.model.tyres import MIN_PEAK_SHARE, _peaks
from online_id.sim.with_effects import predict
from online_id.vehicle.parameters import axle_loads, axle_loads_at
from tests.test_load_transfer import CAR as TRUTH_CAR
from tests.test_load_transfer import TRUTH, K, _cli, braking_slalom, carried, slalom_logs

EXPONENT = 0.7


def test_the_whole_curve_is_scaled_by_the_load_factor_and_the_ellipse():
    """Six loads [Fz1⁰, Fz2⁰, Fx1, Fx2, k1, k2]: the peak at the static load (μ·Fz⁰, derivative Fz⁰) and each curve's
    scale k·√(1 − (Fx/(k·μ·Fz⁰))²), at least k·MIN_PEAK_SHARE, with its exact μ-derivative."""
    mu = np.array([0.9, 1.1])
    loads = np.array([4000.0, 5000.0, -1800.0, 2500.0, 1.2, 0.85])
    peak, dpeak = np.empty(4), np.empty(4)
    _peaks(mu, loads, peak, dpeak)
    np.testing.assert_allclose(peak[:2], [0.9 * 4000, 1.1 * 5000])
    np.testing.assert_allclose(dpeak[:2], [4000, 5000])
    share = np.sqrt(1 - (np.array([-1800, 2500]) / (np.array([1.2, 0.85]) * peak[:2])) ** 2)
    np.testing.assert_allclose(peak[2:], np.array([1.2, 0.85]) * share)
    h = 1e-7
    up = np.empty(4)
    _peaks(mu + h, loads, up, np.empty(4))
    np.testing.assert_allclose((up[2:] - peak[2:]) / h, dpeak[2:], rtol=1e-5)
    _peaks(mu, np.array([4000.0, 5000.0, 3590.0, 0.0, 1.0, 1.0]), peak, dpeak)  # the front's force beyond its ellipse
    assert peak[2] == MIN_PEAK_SHARE and dpeak[2] == 0.0 and peak[3] == 1.0


def test_axle_loads_give_the_static_peak_the_load_factor_and_the_forces():
    effect = EFFECTS["load_sensitivity"](mu_front=0.8, mu_rear=0.85, load_exponent=EXPONENT)
    ax = np.array([-3.0, 0.0, 2.0])
    rows = effect.axle_loads(K, ax)
    static = axle_loads(K)
    np.testing.assert_allclose(rows[:, :2], np.broadcast_to(static, (3, 2)))
    np.testing.assert_allclose(rows[:, 2:4], [[-0.6 * K.M * 3, -0.4 * K.M * 3], [0, 0], [0, K.M * 2]])
    np.testing.assert_allclose(rows[:, 4:], (axle_loads_at(K, ax) / static) ** EXPONENT)
    df = EFFECTS["downforce"](mu_front=0.8, mu_rear=0.85, load_exponent=EXPONENT, downforce_share=0.4)
    speed = np.array([50.0, 25.0, 0.0])
    moved = axle_loads_at(K, ax) + 0.4 * static * (speed[:, None] / 50.0) ** 2
    np.testing.assert_allclose(df.axle_loads(K, ax, speed=speed)[:, 4:], (moved / static) ** EXPONENT)
    with pytest.raises(OnlineIdError, match="follow the speed"):
        df.axle_loads(K, ax)
    assert parse_effect("downforce=0.8:0.85:0.7:0.4").values == df.values
    with pytest.raises(OnlineIdError, match="load exponent"):
        parse_effect("load_sensitivity=0.8:0.85:7")


def test_at_a_steady_speed_it_is_the_axles_law_bit_for_bit():
    """No longitudinal acceleration, no downforce: k = 1 and s = 1, and the kernels take the axles' own arithmetic
    (tire_saturation_axles, bit for bit); with downforce the speed moves the curves."""
    n, dt = 3000, 1e-3
    t = np.arange(n) * dt
    steering = 1.2 * np.sin(2 * np.pi * 0.7 * t)
    speed = np.full(n, 30.0)
    theta = TRUTH.to_vector()
    axles = predict(theta, [EFFECTS["tire_saturation_axles"](mu_front=0.8, mu_rear=0.85)], K, steering, speed, dt,
                    method="rk4")[1]
    for effect in (EFFECTS["load_sensitivity"](mu_front=0.8, mu_rear=0.85, load_exponent=EXPONENT),
                   EFFECTS["downforce"](mu_front=0.8, mu_rear=0.85, load_exponent=EXPONENT, downforce_share=0.0)):
        same = predict(theta, [effect], K, steering, speed, dt, method="rk4", longitudinal_acceleration=np.zeros(n))
        assert np.array_equal(same[1], axles), effect.label
    aero = EFFECTS["downforce"](mu_front=0.8, mu_rear=0.85, load_exponent=EXPONENT, downforce_share=0.5)
    moved = predict(theta, [aero], K, steering, speed, dt, method="rk4", longitudinal_acceleration=np.zeros(n))
    assert np.abs(moved[1] - axles).max() > 1e-3


def test_the_kernels_sensitivities_are_exact_on_scaled_curves():
    """The polish's and the EKF's model (online_id/model/tyres.py) with six loads: its μ and θ sensitivities against
    central differences, through braking and traction at 0.5 g lateral."""
    n, dt, q = 2000, 0.01, 5
    t = np.arange(n) * dt
    delta = 0.02 * np.sin(2 * np.pi * 0.5 * t) + 0.01 * np.sin(2 * np.pi * 1.3 * t)
    V = 30.0 + 5.0 * np.sin(0.2 * t)
    ax = 5.0 * np.sin(2 * np.pi * 0.3 * t)
    W = np.zeros((n, 4))
    W[:, 0] = delta
    effect = EFFECTS["load_sensitivity"](mu_front=0.8, mu_rear=0.85, load_exponent=EXPONENT)
    Fz = tyres.per_sample_loads(effect.axle_loads(K, ax), n)
    kn, theta, mu = tyres.known_array(K), TRUTH.to_vector(), effect.tyre_mu()

    def run(th, m):
        return tyres.simulate_blocks_input(th, m, Fz, W, V, dt, kn, q, 2)

    Y, dY = run(theta, mu)
    assert np.abs(Y[:, 3]).max() > 0.45 * 9.81
    h = 1e-5
    for j in range(2):
        step = np.eye(2)[j] * h
        fd = (run(theta, mu + step)[0] - run(theta, mu - step)[0]) / (2 * h)
        np.testing.assert_allclose(fd, dY[..., 8 + j], atol=1e-6 * np.abs(dY[..., 8 + j]).max(), err_msg=f"μ {j}")
    for p in (0, 2, 3, 6):  # Mzz, D1, D2, b1 (log scale)
        step = np.exp(np.eye(8)[p] * h)
        fd = (run(theta * step, mu)[0] - run(theta / step, mu)[0]) / (2 * h)
        np.testing.assert_allclose(fd, dY[..., p], atol=1e-6 * np.abs(dY[..., p]).max(), err_msg=f"θ {p}")


@pytest.fixture(scope="module")
def sensitive(tmp_path_factory):
    folder = tmp_path_factory.mktemp("sensitive")
    slalom_logs(folder, (5, 6), exponent=EXPONENT)
    return folder


def test_load_sensitivity_is_named_with_its_exponent_and_carried(sensitive):
    """The braking slalom (0.7 g lateral, 0.3 g longitudinal) of a car whose curves follow the load with p = 0.7:
    the diagnosis names load_sensitivity with p within 0.1; the EKF and the UKF carrying it (p as a constant) get
    the 8 within 3 % and μ within 5 %, consistent; the polish holds p and converges."""
    folder = sensitive
    diag = folder / "diag.json"
    _cli("diagnose", folder / "train.csv", "--validate", folder / "held.csv", "--json", diag)
    d = json.loads(diag.read_text())
    named = [c.split(":")[0] for c in d["carry"]["online"]]
    assert named[0] in ("load_sensitivity", "downforce"), d["carry"]
    step = next(st for st in d["refinements"] if st.get("tried") == named[0])
    assert step["significant"], step
    assert step["parameters"]["load_exponent"] == pytest.approx(EXPONENT, abs=0.1), step
    for filt in ("ekf", "ukf"):
        r = carried(folder, diag, filt, named[0], *(["--no-polish"] if filt == "ukf" else []))
        if filt == "ekf":
            polish = r["polish"]
            assert "error" not in polish, polish
            held = polish["effects"][named[0]]["load_exponent"]
            assert held["std"] == 0.0 and held["value"] == pytest.approx(step["parameters"]["load_exponent"], rel=1e-4)


def test_a_plugin_law_written_before_the_speed_was_passed_still_runs():
    """``Effect.axle_loads`` takes the speed since downforce; a plug-in's load-moving law with the older signature
    ``axle_loads(known, longitudinal_acceleration=None)`` is called without it, in the simulation, the polish's
    model and the filters (online_id.effects.base.loads_with_speed)."""
    from online_id.effects.base import loads_with_speed
    from online_id.estimation import make_estimator, run_estimator
    from online_id.sim.simulator import simulate
    from online_id.stream.samples import SampleArrays

    class OldLaw(EFFECTS["load_transfer"]):
        name = "old_law"

        def axle_loads(self, known, longitudinal_acceleration=None):  # (no speed)
            return super().axle_loads(known, longitudinal_acceleration)

    law = OldLaw(mu_front=0.8, mu_rear=0.85)
    ax = np.array([-2.0, 0.0, 2.0])
    np.testing.assert_array_equal(loads_with_speed(law.axle_loads)(K, ax, np.full(3, 30.0)), law.axle_loads(K, ax))
    run = simulate(TRUTH_CAR, TRUTH, duration_s=3.0, rate_hz=100.0, effects=[law]).run
    result = run_estimator(make_estimator(TRUTH_CAR, "ekf", effects=[OldLaw(mu_front=0.8, mu_rear=0.85)]),
                           SampleArrays.from_run(run))
    assert result.samples == len(run.time) and np.all(np.isfinite(result.parameters.to_vector()))


def test_the_diagnosis_tyre_fits_jacobian_is_exact_and_its_loads_follow_the_exponent():
    """The diagnosis's fit of a tyre law takes its Jacobian's columns of θ and μ from the polish's pass with
    sensitivities (:class:`~online_id.batchfit.polish.TyreOutputs`) on the diagnosis's own blocks: each column equals
    central differences of the block means the fit's residuals come from (:class:`~online_id.diagnosis.fitting.
    BlockModel`), also after the load exponent moved (the axle loads formed anew: with the loads of the exponent it
    was built with, μ's column is off by the curves' scale); a sensor effect beside it is chained through."""
    from online_id.batchfit.polish import TyreOutputs
    from online_id.diagnosis.fitting import BlockModel

    run = braking_slalom(seed=3, duration_s=20.0, exponent=EXPONENT)
    model = BlockModel(TRUTH_CAR, run)
    law = EFFECTS["load_sensitivity"](mu_front=0.8, mu_rear=0.85, load_exponent=1.0)
    sensor = next(e for e in EFFECTS["sensor_bias"].candidates(model.channels) if e.channel == "lateral_acceleration")
    sensor = sensor.with_vector([0.3])  # [m/s²]
    exact = TyreOutputs(TRUTH_CAR, run, model.dt, model.q, model.n_blocks, np.inf, np.inf, [law, sensor],
                        model.predictor.intersample)
    theta = TRUTH.to_vector()
    for p in (1.0, EXPONENT):  # the second call moves the held exponent: the loads must follow it
        at = law.with_vector([0.8, 0.85, p])
        values = np.concatenate([at.vector(), sensor.vector()])
        Y, dY = exact(theta, values)
        np.testing.assert_allclose(Y[:, 3], model.outputs(theta, [at, sensor])[:, 3], rtol=0, atol=1e-9)
        h = 1e-5

        def check(column, fd, name, dY=dY, p=p):  # each channel against its own scale (a small channel's error shows)
            for c in range(fd.shape[1]):
                np.testing.assert_allclose(dY[:, c, column], fd[:, c], atol=2e-4 * np.abs(fd[:, c]).max() + 1e-12,
                                           err_msg=f"{name}, channel {c}, p={p}")

        for j, name in ((8, "mu_front"), (9, "mu_rear")):
            lo, hi = (at.with_vector(at.vector() + s * h * np.eye(3)[j - 8]) for s in (-1, 1))
            check(j, (model.outputs(theta, [hi, sensor]) - model.outputs(theta, [lo, sensor])) / (2 * h), name)
        for k in (0, 2, 7):  # Mzz, D1, b2 (log scale)
            step = np.exp(np.eye(8)[k] * h)
            check(k, (model.outputs(theta * step, [at, sensor]) - model.outputs(theta / step, [at, sensor])) / (2 * h),
                  f"θ {k}")
        lo, hi = (sensor.with_vector(sensor.vector() + s * h) for s in (-1, 1))
        check(11, (model.outputs(theta, [at, hi]) - model.outputs(theta, [at, lo])) / (2 * h), "the bias")
        assert not np.any(dY[..., 10]), "the held exponent's column is the fit's to difference"


def test_a_tyre_fit_with_the_exact_jacobian_ends_where_the_differenced_one_does(monkeypatch):
    """fit_family of load_sensitivity on the braking slalom: with the exact columns where Broyden's steps refresh
    their Jacobian and at each closing step (the exponent differenced) and with every column differenced, the same
    minimum (cost within 1e-4, the 8 within 0.2 %, μ and p within 1e-3), the exact one in fewer evaluations (a pass
    with sensitivities, about three plain passes' cost, counted as one)."""
    import online_id.diagnosis.fitting as fitting

    run = braking_slalom(seed=4, duration_s=20.0, exponent=EXPONENT)
    model = fitting.BlockModel(TRUTH_CAR, run)
    train = np.arange(model.n_blocks) >= model.first_block
    law = EFFECTS["load_sensitivity"](mu_front=0.9, mu_rear=0.9, load_exponent=1.0)
    start = TRUTH.to_vector() * np.array([1.1, 0.9, 0.9, 1.1, 1.0, 1.0, 1.2, 0.8])
    exact = fitting.fit_family(model, train, start, [law])
    monkeypatch.setattr(fitting, "EXACT_MIN_COLUMNS", 10 ** 6)
    differenced = fitting.fit_family(model, train, start, [law])
    assert exact.train_rss == pytest.approx(differenced.train_rss, rel=1e-4)
    np.testing.assert_allclose(exact.theta, differenced.theta, rtol=2e-3)
    np.testing.assert_allclose(exact.effects[0].vector(), differenced.effects[0].vector(), atol=1e-3)
    assert exact.effects[0].values["load_exponent"] == pytest.approx(EXPONENT, abs=0.05)
    assert exact.evaluations < differenced.evaluations, (exact.evaluations, differenced.evaluations)


def test_a_tyre_fits_assembled_jacobian_is_its_residuals_derivative(monkeypatch):
    """fit_family's Jacobian as least squares receives it (the exact columns placed among the free θ, the tyre law's
    μ's and its differenced exponent, a sensor effect's bias and a steering offset, each in its scale): every column
    equals central differences of the fit's own residuals at the start, with θ free and with only the effects'
    parameters (a wrong column, scale or order fails it)."""
    import online_id.diagnosis.fitting as fitting

    run = braking_slalom(seed=5, duration_s=12.0, exponent=EXPONENT)
    model = fitting.BlockModel(TRUTH_CAR, run)
    train = np.arange(model.n_blocks) >= model.first_block
    law = EFFECTS["load_sensitivity"](mu_front=0.85, mu_rear=0.9, load_exponent=0.8)
    bias = next(e for e in EFFECTS["sensor_bias"].candidates(model.channels) if e.channel == "lateral_acceleration")
    steer = next(e for e in EFFECTS["sensor_bias"].candidates(model.channels) if e.channel == "steering_wheel_angle")
    effects = [law, bias.with_vector([0.2]), steer.with_vector([0.01])]
    seen = []

    class Stop(Exception):
        pass

    def capture(fun, x0, jac=None, **options):
        seen.append((fun, np.array(x0), jac))
        raise Stop

    monkeypatch.setattr(fitting, "guarded_least_squares", capture)
    for free_theta in (True, False):
        seen.clear()
        with pytest.raises(Stop):
            fitting.fit_family(model, train, TRUTH.to_vector() * 1.05, effects, free_theta=free_theta)
        fun, x0, jac = seen[0]
        J = jac(x0)
        for i in range(len(x0)):
            h = 1e-5 * max(1.0, abs(x0[i]))
            step = np.eye(len(x0))[i] * h
            fd = (fun(x0 + step) - fun(x0 - step)) / (2 * h)
            np.testing.assert_allclose(J[:, i], fd, rtol=0, atol=1e-4 * np.abs(fd).max() + 1e-9,
                                       err_msg=f"column {i} of {len(x0)}, free θ {free_theta}")


def test_a_refinement_whose_default_start_spins_the_car_starts_where_it_does_not():
    """The race log (real data, the first 150 s): from a μ per axle, load_sensitivity's default start p = 1 leaves
    the rear 27 % of its curve under 1 g of braking, and the open-loop car spins (training cost 50× the μ per
    axle's); at 25 Hz the diagnosis's fit never left that point (held-out cost 871 where the μ per axle had 0.35).
    The refinement then starts at the point of its range that costs least, and the fit from there lowers the μ
    per axle's cost with an exponent a tyre can have."""
    from dataclasses import replace

    from online_id.diagnosis.diagnose import BROKEN_START_FACTOR, _good_start, _refined_starts
    from online_id.diagnosis.fitting import BlockModel, fit_family
    from online_id.io.tracklog import read_track_run
    from online_id.vehicle import load_vehicle
    from tests.conftest import SHARED

    car = load_vehicle("revs_250lm")
    run = read_track_run(SHARED / "realdata" / "revs_250lm" / "revs_250lm_laps_0-400s.csv")
    n = 15000
    run = replace(run, **{k: getattr(run, k)[:n] for k in ("time", "steering_wheel_angle", "speed", "yaw_rate",
                                                             "lateral_acceleration", "lateral_velocity",
                                                             "longitudinal_acceleration")})
    model = BlockModel(car, run)
    train = np.arange(model.n_blocks) >= model.first_block
    named = fit_family(model, train, car.prior.to_vector(), [parse_effect("tire_saturation_axles=1.06:1.16")])
    starts = _refined_starts(named.effects[0], EFFECTS["load_sensitivity"], model.channels)
    assert [s.values["load_exponent"] for s in starts] == [1.0, 0.375, 0.75, 1.125]  # the default, then the grid
    assert all(s.values["mu_front"] == named.effects[0].values["mu_front"] for s in starts)

    def cost(effects):
        return float(np.sum(model.residuals(named.theta, effects)[train] ** 2))

    assert cost(starts[:1]) > BROKEN_START_FACTOR * named.train_rss  # the default start spins the car
    chosen = _good_start(named, 0, starts, model, train)
    assert chosen[0] is not starts[0] and cost(chosen) == min(cost([s]) for s in starts)
    assert cost(chosen) < 1.2 * named.train_rss
    fit = fit_family(model, train, named.theta, chosen)
    assert fit.train_rss < 0.95 * named.train_rss
    assert 0.3 < fit.effects[0].values["load_exponent"] < 0.9
    # a start that does not break the model is taken as it is (the fits' results before this guard)
    assert _good_start(named, 0, starts[2:], model, train)[0] is starts[2]
