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
    x, ref, ref_out = x0.copy(), np.empty((n, 6)), np.empty((n, 5))
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


# -- the steering between samples (issue 36) ------------------------------------------------------------------

#: propagate with a steering not held, against the per-sample exact recursion (tests/intersample_reference.py),
#: relative to each state's and output's range (measured 5e-15 to 8e-15: both are exact, modal against expm).
EXACT_STEP_BOUND = 1e-12


@pytest.mark.parametrize("kind", ["linear", "cubic"])
def test_propagate_takes_each_steps_input_polynomial_exactly(car, kind):
    """x ← Ad x + Γ w at each step's speed (the mean of its samples'), y = C x + D δ at each sample's, from a state:
    the compiled recursion against the reference written out, at 100 Hz with the speed stepping mid-run."""
    from intersample_reference import reference_run

    th = car.truth("track")
    n, dt = 1500, 0.01
    dH = maneuvers.chirp(np.arange(n) * dt, np.deg2rad(22.0), duration_s=15.0)
    V = np.where(np.arange(n) < n // 2, 18.0, 26.0)
    x0 = np.array([0.05, -0.01, 0.02, 0.0, 0.003, -0.002])
    states, out = propagate(th, car.known, dH, V, dt, x0=x0, intersample=kind)
    ref_states, ref_out = reference_run(th, car.known, dH, V, dt, kind, x0)
    assert np.all(np.abs(states - ref_states).max(axis=0) <= EXACT_STEP_BOUND * np.abs(ref_states).max(axis=0))
    assert np.all(np.abs(out - ref_out).max(axis=0) <= EXACT_STEP_BOUND * np.abs(ref_out).max(axis=0))


def test_the_hold_is_the_zero_order_hold_recursion_bit_for_bit(car):
    """intersample='hold' (the default) runs the code before issue 36: one ZOH discretisation per distinct speed
    and the compiled x ← Ad x + Bd δ, to the last bit."""
    from online_id.sim.block_loop import sample_recursion

    th = car.truth("track")
    n, dt = 2000, 0.005
    dH = maneuvers.chirp(np.arange(n) * dt, np.deg2rad(22.0), duration_s=10.0)
    V = 20.0 + np.round(np.linspace(0.0, 3.0, n), 1)
    speeds, level = np.unique(V, return_inverse=True)
    Ac, Bc = continuous_matrices(th, speeds, car.known)
    Ad, Bd = discretise_continuous(Ac, Bc, dt)
    C, D = outputs_from_continuous(Ac, Bc, speeds)
    X, Y = np.empty((n, 6)), np.empty((n, 5))
    sample_recursion(*(np.ascontiguousarray(M) for M in (Ad, Bd, C, D)), level.astype(np.int64),
                     dH / car.known.steering_ratio, np.zeros(6), X, Y)
    for states, out in (propagate(th, car.known, dH, V, dt), propagate(th, car.known, dH, V, dt, intersample="hold")):
        assert np.array_equal(states, X) and np.array_equal(out, Y)


def test_a_run_integrated_finely_is_the_cars_own_sampled_with_noise_added_at_the_log_rate(car):
    """simulate(rate_hz=100, integration_rate_hz=10 kHz): the cubic's exact steps at 10 kHz, every 100th fine sample
    logged; the same as integrating at 20 kHz to 1e-6 of the sensor noise (measured 1.3e-8: converged), the
    sensor noise drawn at the logged rate (the same draws as a run integrated at its own rate), and a run
    integrated at its own rate with the hold misses the car by more than the noise (measured 2.3-3.5 σ RMS)."""
    th = car.truth("track")
    noise = SensorNoise()
    sigma = np.array([noise.yaw_rate, noise.roll_angle, noise.roll_rate, noise.lateral_acceleration,
                      noise.lateral_velocity])
    fine = simulate(car, th, duration_s=20.0, rate_hz=100.0, integration_rate_hz=10_000.0, seed=4)
    finer = simulate(car, th, duration_s=20.0, rate_hz=100.0, integration_rate_hz=20_000.0, seed=4)
    held = simulate(car, th, duration_s=20.0, rate_hz=100.0, integration_rate_hz=None, seed=4)
    assert len(fine.run) == len(held.run) == 2000 and np.array_equal(fine.run.time, held.run.time)
    assert fine.run.meta["integration_rate_hz"] == 10_000.0 and "integration_rate_hz" not in held.run.meta
    assert np.array_equal(fine.run.steering_wheel_angle, held.run.steering_wheel_angle)  # the manoeuvre, sampled
    assert np.all(np.abs(fine.outputs - finer.outputs).max(axis=0) < 1e-6 * sigma)
    def noise_drawn(sim):
        r = sim.run
        return np.column_stack([r.yaw_rate, r.roll_angle, r.roll_rate, r.lateral_acceleration]) - sim.outputs[:, :4]

    assert np.allclose(noise_drawn(fine), noise_drawn(held), rtol=0, atol=1e-15)
    assert np.sqrt(np.mean(((held.outputs - fine.outputs) / sigma) ** 2, axis=0)).max() > 1.0


def test_a_varying_speed_integrated_finely_stays_within_its_speed_levels(car):
    """The fine samples' speeds (interpolated between the logged ones) on levels of FINE_SPEED_TOLERANCE: within a
    tenth of it of the fine run with one discretisation per distinct speed, relative to each output's range
    (measured 2e-6)."""
    from online_id.sim.simulator import FINE_SPEED_TOLERANCE

    th = car.truth("track")
    V = np.linspace(15.0, 25.0, 400)
    sim = simulate(car, th, duration_s=4.0, rate_hz=100.0, integration_rate_hz=2000.0, speed_mps=V,
                   noise=SensorNoise.none())
    t_fine = np.arange(399 * 20 + 1) / 2000.0
    dH = maneuvers.chirp(t_fine, np.deg2rad(22.0), duration_s=4.0)
    _, exact = propagate(th, car.known, dH, np.interp(t_fine, sim.run.time, V), 1 / 2000.0, intersample="cubic")
    err = np.abs(sim.outputs - exact[::20]).max(axis=0) / np.abs(exact).max(axis=0)
    assert np.all(err < 0.1 * FINE_SPEED_TOLERANCE), err


def test_effects_integrated_finely_are_applied_at_the_fine_rate(car):
    """A saturating tyre (the filters' RK4, each fine step's input at its midpoint) against the force-law loop
    at the fine rate with δ exact through Γ (online_id/sim/forces.py), both at 5 kHz: within 1e-3 of the noise
    (measured 3.6e-4 at 0.8 g);
    a yaw-rate delay is applied to the fine signal before it is logged."""
    from online_id.effects import parse_effect
    from online_id.sim.with_effects import predict

    th = car.truth("track")
    noise = SensorNoise()
    sigma = np.array([noise.yaw_rate, noise.roll_angle, noise.roll_rate, noise.lateral_acceleration,
                      noise.lateral_velocity])
    tyre = parse_effect("tire_saturation=0.7")
    sim = simulate(car, th, duration_s=2.0, rate_hz=100.0, amplitude_rad=np.deg2rad(60.0), effects=[tyre],
                   integration_rate_hz=5000.0, noise=SensorNoise.none())
    t_fine = np.arange(199 * 50 + 1) / 5000.0
    dH = maneuvers.chirp(t_fine, np.deg2rad(60.0), duration_s=2.0)
    _, loop = predict(th.to_vector(), [tyre], car.known, dH, sim.run.speed[0], 1 / 5000.0, method="loop",
                      intersample="cubic")
    assert np.all(np.abs(sim.outputs - loop[::50]).max(axis=0) < 1e-3 * sigma)
    delay = parse_effect("sensor_delay=yaw_rate:0.013")
    delayed = simulate(car, th, duration_s=2.0, rate_hz=100.0, effects=[delay], integration_rate_hz=5000.0,
                       noise=SensorNoise.none())
    base = simulate(car, th, duration_s=2.0, rate_hz=100.0, integration_rate_hz=5000.0, noise=SensorNoise.none())
    _, car_fine = propagate(th, car.known, maneuvers.chirp(t_fine, np.deg2rad(22.0), duration_s=2.0),
                            base.run.speed[0], 1 / 5000.0, intersample="cubic")
    late = np.interp(sim.run.time - 0.013, t_fine, car_fine[:, 0], left=0.0)  # 13 ms: between logged samples
    assert np.allclose(delayed.outputs[:, 0], late, rtol=0, atol=1e-12)
    assert np.array_equal(delayed.outputs[:, 1:], base.outputs[:, 1:])


def test_a_long_fine_run_is_integrated_in_chunks_with_the_same_numbers(car, monkeypatch):
    """The fine samples go through in chunks (FINE_CHUNK: memory), each from the state the last ended at and its
    step inputs from the samples around it: the same numbers as in one chunk, to the bit at a constant speed."""
    import online_id.sim.simulator as simulator

    th = car.truth("track")
    whole = simulate(car, th, duration_s=3.0, rate_hz=100.0, integration_rate_hz=2000.0)
    monkeypatch.setattr(simulator, "FINE_CHUNK", 7)  # (at least one logged sample a chunk: 20 fine samples)
    chunked = simulate(car, th, duration_s=3.0, rate_hz=100.0, integration_rate_hz=2000.0)
    assert np.array_equal(chunked.outputs, whole.outputs) and np.array_equal(chunked.states, whole.states)
