"""Handling metrics (online_id/handling): against the closed forms of the linear model, their σ against the spread
of draws from the covariance they are propagated from, and the run's measured response against the model's."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from online_id.handling import handling
from online_id.handling.measured import measured_response
from online_id.handling.metrics import understeer_gradient, yaw_mode, yaw_rate_gain
from online_id.sim.simulator import simulate
from online_id.units import G
from online_id.vehicle import PARAMETER_NAMES, load_vehicle

DEG = 180 / math.pi
#: The issue's tolerance on the closed forms (understeer gradient, characteristic speed).
CLOSED_FORM = 1e-3


@pytest.fixture(scope="module")
def car():
    return load_vehicle("haro2008")


def _bicycle(known, theta):
    """K [rad per m/s²] of the bicycle model from D1, D2, M, l1, l2, and L."""
    L = known.l1 + known.l2
    return known.M / L * (known.l2 / theta[2] - known.l1 / theta[3]), L


def test_understeer_gradient_and_characteristic_speed_are_the_bicycle_models_without_roll_steer(car):
    """With no roll steer (ε1 = ε2 = 0) the full model's steady state gives the bicycle model's K =
    (M/L)(l2/D1 − l1/D2) at any speed, and the characteristic speed √(L/K); the roll adds nothing in a steady
    turn."""
    known = replace(car.known, eps1=0.0, eps2=0.0)
    theta = car.truth("track").to_vector()
    K, L = _bicycle(known, theta)
    for speed in (10.0, 22.2, 40.0):
        assert understeer_gradient(theta, speed, known) == pytest.approx(K, rel=CLOSED_FORM)
    h = handling(theta, np.diag((0.01 * theta) ** 2), known, 22.2)
    assert h.understeer_gradient.value == pytest.approx(K * G * DEG, rel=CLOSED_FORM)
    assert h.speed_kind == "characteristic"
    assert h.characteristic_speed.value == pytest.approx(math.sqrt(L / K), rel=CLOSED_FORM)
    # the steady yaw-rate gain is V / (L + K V²) per road-wheel angle, over the steering ratio
    for v in (5.0, 22.2, 60.0):
        assert yaw_rate_gain(theta, v, known) == pytest.approx(v / (L + K * v * v) / known.steering_ratio,
                                                               rel=CLOSED_FORM)
    # the gain peaks at the characteristic speed
    peak = h.gain_speeds_mps[np.argmax(h.gain_by_speed)]
    assert abs(peak - h.characteristic_speed.value) <= np.diff(h.gain_speeds_mps)[0]


def test_roll_steer_adds_its_term_and_an_oversteering_car_has_a_critical_speed(car):
    known, theta = car.known, car.truth("track").to_vector()
    K, L = _bicycle(known, theta)
    roll_steer = -(known.eps1 - known.eps2) * known.ms * known.h0 / theta[PARAMETER_NAMES.index("Kro")]
    assert understeer_gradient(theta, 22.2, known) == pytest.approx(K + roll_steer, rel=CLOSED_FORM)
    over = theta.copy()
    over[2], over[3] = 2.5 * theta[3], 0.6 * theta[2]  # a stiff front axle: oversteer
    no_roll_steer = replace(known, eps1=0.0, eps2=0.0)
    K_over, _ = _bicycle(no_roll_steer, over)
    assert K_over < 0
    h = handling(over, None, no_roll_steer, 15.0)
    assert h.speed_kind == "critical" and h.understeer_gradient.value < 0
    assert h.characteristic_speed.value == pytest.approx(math.sqrt(-L / K_over), rel=CLOSED_FORM)
    assert h.understeer_gradient.std is None  # no covariance: no σ, never a made-up one


def test_the_yaw_mode_is_the_six_state_models_in_the_two_degree_of_freedom_limit(car):
    """Relaxation lengths of 10 µm, no roll coupling (h0 → 0, Mxz = 0) and no roll steer: the 6-state model has
    a pair of eigenvalues, the two that take the largest part in r and β (participation factors), with
    λ1·λ2 = ωn² and −(λ1 + λ2) = 2ζωn of :func:`yaw_mode`'s closed form."""
    from online_id.model.lateral import BETA, R, continuous_matrices

    known = replace(car.known, h0=1e-6, Mxz=0.0, eps1=0.0, eps2=0.0, h1=0.0, h2=0.0)
    theta = car.truth("track").to_vector().copy()
    theta[PARAMETER_NAMES.index("b1")] = theta[PARAMETER_NAMES.index("b2")] = 1e-5
    for V in (15.0, 30.0):
        lam, right = np.linalg.eig(continuous_matrices(theta, V, known)[0])
        left = np.linalg.inv(right)
        share = np.abs(right[R] * left[:, R]) + np.abs(right[BETA] * left[:, BETA])
        l1, l2 = lam[np.argsort(-share)[:2]]
        wn, zeta = yaw_mode(theta, V, known)
        assert float(wn) == pytest.approx(math.sqrt(np.real(l1 * l2)), rel=CLOSED_FORM)
        assert float(zeta) == pytest.approx(-np.real(l1 + l2) / (2 * float(wn)), rel=CLOSED_FORM)


def test_sigma_is_the_spread_of_the_metrics_over_draws_from_the_covariance(car):
    """First-order propagation against 4,000 draws of θ from the covariance (1-3 % per parameter, correlated
    as a filter's are): each metric's σ within 10 % of the draws' spread."""
    rng = np.random.default_rng(7)
    theta = car.truth("track").to_vector()
    rel = np.array([0.02, 0.03, 0.015, 0.015, 0.03, 0.02, 0.03, 0.02])
    corr = np.full((8, 8), 0.3) + 0.7 * np.eye(8)
    cov_s = corr * np.outer(rel, rel)
    h = handling(theta, cov_s * np.outer(theta, theta), car.known, 22.2)
    draws = theta * np.exp(rng.multivariate_normal(np.zeros(8), cov_s, size=4000))
    speed = 22.2
    K = understeer_gradient(draws, speed, car.known) * G * DEG
    gain = yaw_rate_gain(draws, speed, car.known)
    wn, zeta = yaw_mode(draws, speed, car.known)
    for metric, spread in ((h.understeer_gradient, K.std()), (h.yaw_rate_gain, gain.std()),
                           (h.yaw_frequency, (wn / (2 * math.pi)).std()), (h.yaw_damping, zeta.std())):
        assert metric.std == pytest.approx(spread, rel=0.1), metric


def test_a_parameter_the_data_did_not_determine_leaves_what_depends_on_it_without_sigma(car):
    theta = car.truth("track").to_vector()
    cov = np.diag((0.01 * theta) ** 2)
    cov[0, 0] = np.inf  # Mzz not determined (a fit's null σ)
    h = handling(theta, cov, car.known, 22.2)
    assert h.understeer_gradient.std is not None  # a steady turn does not depend on the yaw inertia
    assert h.yaw_frequency.std is None and h.yaw_damping.std is None
    assert np.isnan(h.response.magnitude_std).any()
    assert h.to_json_dict()["yaw_natural_frequency"]["std"] is None


def test_the_measured_response_of_a_chirp_lies_on_the_models_and_a_straight_line_has_none(car):
    truth = car.truth("track")
    run = simulate(car, truth, duration_s=30.0, rate_hz=200.0, seed=2).run
    h = handling(truth.to_vector(), None, car.known, float(np.median(run.speed)), run=run)
    m = h.measured
    assert len(m.frequency_hz) >= 10 and m.frequency_hz.min() < 0.5 and m.frequency_hz.max() > 3.0
    model = np.interp(m.frequency_hz, h.response.frequency_hz, h.response.magnitude)
    assert np.median(np.abs(m.magnitude / model - 1)) < 0.05
    assert np.all(m.frequency_hz <= 4.5)  # nothing above the chirp's end: no input there to measure with
    straight = simulate(car, truth, duration_s=30.0, rate_hz=200.0, maneuver="sine", amplitude_rad=0.0, seed=2).run
    empty = measured_response(straight)
    assert len(empty.frequency_hz) == 0 and "did not excite" in empty.summary()
