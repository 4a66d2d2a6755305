"""Online estimators: recovery of known parameters from simulated runs, guards, honesty of σ.

Identification tests simulate the Table 6 (or Table 5) car with sensor noise, run the filter
from the constructor prior (or from 0.5× / 2× truth) and require every parameter within the
issue's tolerance of truth and within 3 of its reported σ.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from online_id.estimation import make_estimator, run_estimator
from online_id.filters import EKFEstimator, FilterConfig
from online_id.model.lateral import N_STATES
from online_id.sim.simulator import simulate
from online_id.stream.samples import Sample, samples_from_run
from online_id.vehicle import PARAMETER_NAMES, load_vehicle

TOLERANCE = {"ekf": 0.005, "ukf": 0.01}
NO_ROLL_TOLERANCE = 0.02


@pytest.fixture(scope="module")
def car():
    return load_vehicle("haro2008")


@pytest.fixture(scope="module")
def run80(car):
    return simulate(car, car.truth("track"), speed_mps=80 / 3.6, seed=1).run


@pytest.fixture(scope="module")
def run60(car):
    return simulate(car, car.truth("track60"), speed_mps=60 / 3.6, seed=2).run


def _estimate(car, run, filt, channels=None, **kw):
    est = make_estimator(car, filt, **kw)
    return run_estimator(est, samples_from_run(run, channels), truth=None)


def _check(result, truth, tol, what):
    err = result.parameters.to_vector() / truth.to_vector() - 1
    z = err / result.relative_std
    report = ", ".join(f"{n} {100 * e:+.3f}% ({zz:+.1f}σ)" for n, e, zz in zip(PARAMETER_NAMES, err, z))
    assert np.all(np.abs(err) < tol), f"{what}: not all within {100 * tol:g}%: {report}"
    assert np.all(np.abs(z) < 3), f"{what}: not all within 3σ: {report}"


@pytest.mark.parametrize("filt", ["ekf", "ukf"])
def test_recovers_table6_from_the_constructor_prior(car, run80, filt):
    res = _estimate(car, run80, filt)
    _check(res, car.truth("track"), TOLERANCE[filt], f"{filt} 80 km/h")
    assert all(res.informed.values())
    assert res.events.get("resets", 0) == 0 and res.events.get("outliers_rejected", 0) == 0


@pytest.mark.parametrize("filt", ["ekf", "ukf"])
@pytest.mark.parametrize("scale", [0.5, 2.0])
def test_recovers_from_initial_values_at_half_and_twice_truth(car, run80, filt, scale):
    truth = car.truth("track")
    res = _estimate(car, run80, filt, initial=truth.scaled(scale))
    _check(res, truth, TOLERANCE[filt], f"{filt} from {scale}× truth")


@pytest.mark.parametrize("filt", ["ekf", "ukf"])
def test_recovers_table5_on_the_60kmh_run(car, run60, filt):
    res = _estimate(car, run60, filt)
    _check(res, car.truth("track60"), TOLERANCE[filt], f"{filt} 60 km/h")


@pytest.mark.parametrize("filt", ["ekf", "ukf"])
def test_without_the_roll_channel(car, run80, filt):
    res = _estimate(car, run80, filt, channels=("yaw_rate", "lateral_acceleration"))
    _check(res, car.truth("track"), NO_ROLL_TOLERANCE, f"{filt} without roll")


def test_weak_excitation_leaves_parameters_near_the_prior_and_flags_them(car):
    """A gentle 0.2 Hz sine of 2° steering-wheel amplitude cannot inform the dynamic parameters."""
    run = simulate(car, car.truth("track"), duration_s=30.0, rate_hz=200.0, maneuver="sine",
                   amplitude_rad=np.deg2rad(2.0), frequency_hz=0.2, seed=5).run
    res = _estimate(car, run, "ekf")
    not_informed = [n for n, ok in res.informed.items() if not ok]
    assert {"Mzz", "b1", "b2"} <= set(not_informed), res.informed
    # what it could not learn stays within its prior spread of the prior value
    prior = car.prior.to_vector()
    for i, n in enumerate(PARAMETER_NAMES):
        if n in not_informed:
            assert abs(np.log(res.parameters.to_vector()[i] / prior[i])) < res.prior_relative_std[i], n
    # a quasi-static turn does inform the roll stiffness (roll angle = ms h0 a_y / Kro)
    assert res.informed["Kro"]


def _corrupt(run, rng):
    """NaN samples, 10σ spikes in 1 % of samples, a 2 s dropout, and speed falling to 0 and back."""
    n = len(run)
    time = run.time.copy()
    cols = {c: getattr(run, c).copy() for c in ("steering_wheel_angle", "speed", "yaw_rate",
                                                 "lateral_acceleration", "roll_angle", "roll_rate")}
    sd = {"yaw_rate": 0.004, "lateral_acceleration": 0.05, "roll_angle": 0.0005, "roll_rate": 0.004}
    for c, s in sd.items():
        idx = rng.choice(n, n // 100, replace=False)
        cols[c][idx] += 10 * s * rng.choice([-1, 1], len(idx))
    nan_idx = rng.choice(n, 50, replace=False)
    cols["yaw_rate"][nan_idx[:25]] = np.nan
    cols["speed"][nan_idx[25:]] = np.nan
    # speed falls to 0 and back between 20 s and 23 s (the car stops; the model cannot follow)
    stop = (time > 20.0) & (time < 23.0)
    cols["speed"][stop] = np.abs(np.sin(np.pi * (time[stop] - 20.0) / 3.0)) * 0.0
    keep = ~((time > 40.0) & (time < 42.0))  # a 2 s dropout
    samples = []
    for k in np.flatnonzero(keep):
        samples.append(Sample(time[k], cols["steering_wheel_angle"][k], cols["speed"][k], cols["yaw_rate"][k],
                              cols["lateral_acceleration"][k], cols["roll_angle"][k], cols["roll_rate"][k]))
    return samples


@pytest.mark.parametrize("filt", ["ekf", "ukf"])
def test_bad_data_is_counted_and_does_not_spoil_the_estimate(car, run80, filt):
    samples = _corrupt(run80, np.random.default_rng(7))
    est = make_estimator(car, filt)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a reset would warn: none should be needed here
        res = run_estimator(est, samples)
    ev = res.events
    assert ev["samples"] == len(samples)
    assert ev["invalid_samples"] == sum(np.isnan(s.speed) for s in samples) > 0  # NaN speed: unusable
    assert ev["missing_values"] >= 1  # NaN yaw rate: that channel skipped
    assert ev["gaps"] == 1
    assert ev["frozen_low_speed"] > 2000
    assert ev["outliers_rejected"] > 0 and set(res.gated) == {"yaw_rate", "lateral_acceleration",
                                                              "roll_angle", "roll_rate"}
    _check(res, car.truth("track"), TOLERANCE[filt], f"{filt} with bad data")


def test_ekf_groups_give_the_sample_by_sample_result(car, run80):
    """The EKF works samples in groups (Toeplitz products of powers of Ad). Reading the model
    states after every sample forces groups of one, i.e. the plain per-sample recursion: mean,
    covariance, estimates and every count must come out the same, spikes and gaps included."""
    samples = _corrupt(run80, np.random.default_rng(3))  # spikes, NaN, a stop, a dropout
    grouped, single = make_estimator(car, "ekf"), make_estimator(car, "ekf")
    for s in samples:
        grouped.update(s)
        single.update(s)
        single.x  # noqa: B018 -- reading the states works the pending samples now
    assert grouped.events["corrections"] > 100 and grouped.events["outliers_rejected"] > 0
    assert grouped.events == single.events and grouped.gated == single.gated
    np.testing.assert_allclose(grouped.x, single.x, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(grouped.P, single.P, rtol=1e-8, atol=1e-16)


def test_streaming_estimate_is_readable_at_any_moment(car, run80):
    est = EKFEstimator(car)
    for k, s in enumerate(samples_from_run(run80.slice(0, 3000))):
        est.update(s)
        if k in (0, 1500, 2999):
            p, sd = est.parameters, est.parameter_std
            assert np.all(np.isfinite(p.to_vector())) and np.all(sd > 0)
    assert est.events["samples"] == 3000


def test_no_crash_on_garbage_and_a_reset_restores_the_last_good_state(car):
    est = EKFEstimator(car)
    est.update(Sample(0.0, 0.0, 20.0, 0.0, 0.0))
    est.update(Sample(0.0, 0.0, 20.0, 0.0, 0.0))  # repeated time
    est.update(Sample(-1.0, 0.0, 20.0, 0.0, 0.0))  # time going back
    est.update(Sample(float("inf"), 0.0, 20.0, 0.0, 0.0))
    assert est.events["invalid_samples"] == 3
    good = est.parameters
    # force a broken covariance: the next correction must reset, warn once, and keep going
    P = est.P.copy()
    P[N_STATES, N_STATES] = np.nan
    est._set(est.x.copy(), P)
    with pytest.warns(RuntimeWarning, match="reset to the last good state"):
        for k in range(1, 30):
            est.update(Sample(k * 1e-3, 0.01, 20.0, 0.001, 0.01, 0.0, 0.0))
    assert est.events["resets"] >= 1
    assert np.allclose(est.parameters.to_vector(), good.to_vector(), rtol=0.2)
    assert np.all(np.isfinite(est.P))


def test_ekf_accumulated_jacobian_matches_finite_differences(car):
    """F_total = ∂(state after n samples)/∂(augmented state before), chained sample by sample."""
    cfg = FilterConfig(correct_every=10)
    est = EKFEstimator(car, config=cfg)
    x0 = est.x.copy()
    x0[:N_STATES] = [0.1, 0.01, 0.01, 0.05, 0.01, 0.005]
    x0[N_STATES:] = np.log(car.truth("track").to_vector() / car.prior.to_vector())
    # each step's input between its samples (model/intersample.py): value and derivatives in normalised time
    inputs = [(1e-3, np.array([0.02 * np.sin(k / 5), 0.004 * np.cos(k / 5), -8e-4 * np.sin(k / 5), -1.6e-4]), 22.0)
              for k in range(8)]

    def advance(x):
        e = EKFEstimator(car, config=cfg)
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
    assert np.abs(F - num).max() / np.abs(num).max() < 1e-5


def test_filter_config_rejects_nonsense():
    with pytest.raises(ValueError):
        FilterConfig(correct_every=0)
    with pytest.raises(ValueError):
        FilterConfig(measurement_std={"yaw_rate": 0.0})


def test_adaptive_r_keeps_sigma_honest_when_the_sensors_are_noisier_than_configured(car):
    """Sensor noise 3× the configured R: covariance matching learns R ≈ 9× and σ stays honest."""
    from online_id.sim.simulator import SensorNoise

    n = SensorNoise()
    noisy = SensorNoise(3 * n.yaw_rate, 3 * n.lateral_acceleration, 3 * n.roll_angle, 3 * n.roll_rate)
    run = simulate(car, car.truth("track"), seed=3, noise=noisy).run
    zs = {}
    for window in (0.5, 0.0):
        est = EKFEstimator(car, config=FilterConfig(adaptive_r_window_s=window))
        est.update_many(samples_from_run(run))
        err = est.parameters.to_vector() / car.truth("track").to_vector() - 1
        zs[window] = np.abs(err / est.log_scale_std).max()
        if window:
            scale = (est._R_diag / est._R_nominal)[:4]  # (the four channels measured; no lateral velocity)
            assert np.all((scale > 5) & (scale < 13)), scale
    assert zs[0.5] < 3, zs
    assert zs[0.0] > zs[0.5], zs  # without it the filter is overconfident
