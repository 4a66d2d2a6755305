"""The simulator: noise levels as asked, per-sample speed, protocol inputs."""

from __future__ import annotations

import numpy as np
import pytest

from online_id.model.discretise import discretise_continuous
from online_id.model.lateral import continuous_matrices, outputs_from_continuous
from online_id.sim import maneuvers
from online_id.sim.simulator import SensorNoise, propagate, simulate
from online_id.vehicle import load_vehicle


@pytest.fixture(scope="module")
def car():
    return load_vehicle("haro2008")


def test_noise_has_the_requested_standard_deviation(car):
    sim = simulate(car, car.truth("track"), duration_s=20.0, seed=3)
    run, clean = sim.run, sim.outputs
    noise = SensorNoise()
    for got, ref, sd in [(run.yaw_rate, clean[:, 0], noise.yaw_rate), (run.roll_angle, clean[:, 1], noise.roll_angle),
                         (run.roll_rate, clean[:, 2], noise.roll_rate),
                         (run.lateral_acceleration, clean[:, 3], noise.lateral_acceleration)]:
        assert np.std(got - ref) == pytest.approx(sd, rel=0.03)


def test_per_sample_speed_equals_constant_speed_when_constant(car):
    th = car.truth("track")
    a = simulate(car, th, duration_s=2.0, speed_mps=20.0, noise=SensorNoise.none())
    b = simulate(car, th, duration_s=2.0, speed_mps=np.full(2000, 20.0), noise=SensorNoise.none())
    assert np.array_equal(a.outputs, b.outputs)


def test_varying_speed_run_changes_the_response(car):
    th = car.truth("track")
    V = np.linspace(15.0, 25.0, 4000)
    a = simulate(car, th, duration_s=4.0, speed_mps=V, noise=SensorNoise.none(), maneuver="step")
    b = simulate(car, th, duration_s=4.0, speed_mps=15.0, noise=SensorNoise.none(), maneuver="step")
    assert a.run.meta["speed_mps"] == "varying"
    # steady yaw rate per unit steer rises with speed below the characteristic speed
    assert a.outputs[-1, 0] > 1.1 * b.outputs[-1, 0]


@pytest.mark.parametrize("varying", [False, True])
def test_the_compiled_recursion_from_a_state_equals_the_plain_loop(car, varying):
    """propagate's compiled recursion (online_id/sim/block_loop.py) against x ← Ad x + Bd δ written out, each
    sample at its own speed, from a non-zero state."""
    th = car.truth("track")
    n, dt = 3000, 1e-3
    dH = maneuvers.chirp(np.arange(n) * dt, np.deg2rad(22.0), duration_s=3.0)
    V = np.where(np.arange(n) < n // 2, 18.0, 26.0) + (np.linspace(0.0, 0.5, n) if varying else 0.0)
    x0 = np.array([0.05, -0.01, 0.02, 0.0, 0.003, -0.002])
    states, out = propagate(th, car.known, dH, V, dt, x0=x0)
    Ac, Bc = continuous_matrices(th, V, car.known)
    Ad, Bd = discretise_continuous(Ac, Bc, dt)
    C, D = outputs_from_continuous(Ac, Bc, V)
    delta = dH / car.known.steering_ratio
    x, ref, ref_out = x0.copy(), np.empty((n, 6)), np.empty((n, 4))
    for k in range(n):
        ref[k], ref_out[k] = x, C[k] @ x + D[k] * delta[k]
        x = Ad[k] @ x + Bd[k] * delta[k]
    scale = np.abs(ref).max(axis=0)
    assert np.all(np.abs(states - ref).max(axis=0) <= 1e-12 * scale)
    assert np.all(np.abs(out - ref_out).max(axis=0) <= 1e-12 * np.abs(ref_out).max(axis=0))
    assert np.array_equal(states[0], x0)


def test_chirp_sweeps_0p2_to_4hz_from_zero():
    t = np.arange(60000) / 1000.0
    s = maneuvers.chirp(t, 1.0, duration_s=60.0)
    assert s[0] == 0.0 and np.abs(s).max() == pytest.approx(1.0, abs=1e-6)
    f = maneuvers.chirp_frequency(t, duration_s=60.0)
    assert f[0] == pytest.approx(0.2) and f[-1] == pytest.approx(4.0, abs=1e-3)
    # zero crossings in the last second: about 2 × 4 Hz
    last = s[-1000:]
    assert 7 <= np.count_nonzero(np.diff(np.sign(last))) <= 9


def test_bad_simulation_requests(car):
    with pytest.raises(ValueError, match="unknown maneuver"):
        simulate(car, car.prior, maneuver="slalom")
    with pytest.raises(ValueError, match="positive speed"):
        simulate(car, car.prior, speed_mps=0.0)
