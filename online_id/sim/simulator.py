"""Simulated track runs: the lateral model driven by a steering input, plus sensor noise.

The model is advanced with its exact discretisation, the speed scheduled sample by sample (one
discretisation per distinct speed); the recursions are compiled (:mod:`online_id.sim.block_loop`).

A data logger samples a continuous car (issue 36): :func:`simulate` integrates the car finer than it
logs (``integration_rate_hz``, by default :data:`FINE_RATE_HZ`): k = ⌈integration rate / log rate⌉ sub-steps
a logged sample, the manoeuvre evaluated at the fine times, the speed profile interpolated linearly to them,
the exact step with the cubic input between the fine samples (:mod:`online_id.model.intersample`; at 10 kHz
the cubic reproduces a 4 Hz chirp to ~1e-9 of its amplitude over a step), effects applied at the fine rate;
then every k-th fine sample is logged and the sensor noise is added at the logged rate. At the logged rate
itself (``integration_rate_hz`` None) the steering is held over each sample (zero-order hold), as before
issue 36: the filters' own discretisation of their own input, which hides the hold's half-sample lag from
every test built that way.

Cost (benchmarks/bench_simulate.py, best of 5 on a shared machine, load 7 on 2 cores): the built-in 60 s chirp
logged at 1 kHz, no effects, 50 ms at the logged rate, 180 ms integrated at 10 kHz (600,000 fine steps: the
manoeuvre, the step polynomials and the compiled recursion, about a third each); logged at 100 Hz, 19 ms and
145 ms; 20 s of a 60° chirp with ``tire_saturation=0.7`` (0.8 g) logged at 100 Hz, 0.7 s at the logged rate (the
trapezoid's loop) and 2.3-3.2 s at 10 kHz (the filters' compiled RK4 model, each fine step's input at its
midpoint: :func:`online_id.sim.with_effects.predict`'s ``"midpoint"``; the same as at 20 kHz to 1e-4 of the
sensor noise).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from online_id.effects.base import in_stage_order
from online_id.io.tracklog import TrackRun, speed_slope
from online_id.model import intersample as its
from online_id.model.discretise import discretise_continuous
from online_id.model.lateral import BETA, N_STATES, VY, R, continuous_matrices, outputs_from_continuous
from online_id.sim import maneuvers
from online_id.sim.block_means import step_inputs
from online_id.sim.levels import geometric_levels, modal_form
from online_id.sim.maneuvers import SpeedProfile
from online_id.sim.with_effects import car_inputs, has_force_law, logged_outputs, predict
from online_id.vehicle.loader import Vehicle
from online_id.vehicle.parameters import Parameters

#: A logger's car: an internal step of at most 0.1 ms (module docstring).
FINE_RATE_HZ = 10_000.0
#: The rate [Hz] :func:`simulate` integrates the car at by default, finer than it logs (module docstring):
#: a logger samples a continuous car. None: at the logged rate with the steering held over each sample (the
#: behaviour before issue 36; ``--integration-rate 0`` on the command line).
INTEGRATION_RATE_HZ: float | None = FINE_RATE_HZ
#: Relative width of the speed levels of a varying speed integrated at the fine rate (one discretisation per
#: level, not per fine sample): the speed is within 5e-5 of each sample's; measured on a 15-25 m/s ramp, the
#: outputs within 2e-6 of their range of those with one discretisation per distinct speed.
FINE_SPEED_TOLERANCE = 1e-4
#: Fine samples integrated at once without effects (about 120 bytes a fine sample: 60 MB a chunk, 52 s at 10 kHz).
FINE_CHUNK = 1 << 19
#: Samples of a speed block in the force-law simulation at the fine rate [s] (the speed held at its mean over
#: each: under 0.01 m/s of change at 1 g); 1 ms keeps that solver's per-block arrays the size of a 1 kHz run's.
FINE_FORCE_BLOCK_S = 1e-3


@dataclass(frozen=True)
class SensorNoise:
    """Standard deviation of white sensor noise per channel (SI units). Zero means exact."""

    yaw_rate: float = 0.004              # rad/s
    lateral_acceleration: float = 0.05   # m/s²
    roll_angle: float = 0.0005           # rad
    roll_rate: float = 0.004             # rad/s
    lateral_velocity: float = 0.02       # m/s (an INS's or an optical sideslip sensor's, when logged)
    longitudinal_acceleration: float = 0.05  # m/s² (when logged)

    @classmethod
    def none(cls) -> SensorNoise:
        return cls(0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


@dataclass
class Simulation:
    """Noise-free states and outputs of a simulation, with the run as logged.

    Attributes
    ----------
    run : the logged run (outputs with noise)
    states : (N, 6) model states [r, β, φ, p, α1, α2]
    outputs : (N, 5) noise-free outputs [r, φ, p, a_y, v_y]
    """

    run: TrackRun
    states: np.ndarray
    outputs: np.ndarray


def propagate(theta, known, steering_wheel_angle, speed, dt: float, x0=None, intersample: str = "hold",
              every: int = 1, speed_tolerance: float = 0.0):
    """States (N, 6) and noise-free outputs (N, 4) for the given inputs.

    ``steering_wheel_angle`` [rad] and ``speed`` [m/s] have shape (N,) (speed
    may be a scalar). ``intersample`` is the input between two samples a period ``dt`` [s] apart: ``"hold"``
    (held over the period: x[k+1] = Ad x[k] + Bd δ[k]) or ``"linear"``/``"cubic"``
    (:mod:`online_id.model.intersample`: x[k+1] = Ad x[k] + Γ w[k], exact for the polynomial w[k], at the
    step's speed, the mean of its two samples'; Ad and Γ mode by mode, :func:`online_id.sim.levels.modal_form`).
    With the latter, ``every`` > 1 keeps the states and outputs of every ``every``-th sample only (a run
    integrated finer than it is logged: (⌈N / every⌉, 6) and (⌈N / every⌉, 4)), and ``speed_tolerance`` > 0
    takes the speeds on levels of that relative width (:func:`online_id.sim.levels.geometric_levels`) instead of
    one discretisation per distinct speed.
    """
    dH = np.asarray(steering_wheel_angle, dtype=float)
    n = len(dH)
    V = np.broadcast_to(np.asarray(speed, dtype=float), (n,))
    delta = dH / known.steering_ratio
    x = np.zeros(N_STATES) if x0 is None else np.asarray(x0, dtype=float).copy()
    if its.check_kind(intersample) != "hold":
        W, step_speed = step_inputs(intersample, delta, V, dt)
        return _propagate_inputs(theta, known, delta, V, W, step_speed, dt, x, intersample, int(every),
                                 speed_tolerance)
    if every != 1 or speed_tolerance:
        raise ValueError("propagate: every and speed_tolerance are for a steering that is not held")
    states = np.empty((n, N_STATES))
    speeds, inverse = np.unique(V, return_inverse=True)
    Ac, Bc = continuous_matrices(theta, speeds, known)
    Ad, Bd = discretise_continuous(Ac, Bc, dt)
    C, D = outputs_from_continuous(Ac, Bc, speeds)
    from online_id.sim.block_loop import sample_recursion  # compiled (numba), imported when first needed

    out = np.empty((n, C.shape[-2]))
    sample_recursion(*(np.ascontiguousarray(M) for M in (Ad, Bd, C, D)), np.ascontiguousarray(inverse, dtype=np.int64),
                     np.ascontiguousarray(delta), x, states, out)
    return states, out


def _propagate_inputs(theta, known, delta, V, W, step_speed, dt, x, kind, every, speed_tolerance):
    """:func:`propagate` with the steering between samples of ``kind`` (not the hold): each sample's step input
    ``W`` (n, 4) and speed ``step_speed`` (n,) given (:func:`online_id.sim.block_means.step_inputs`)."""
    from online_id.sim.block_loop import input_recursion  # compiled (numba), imported when first needed

    n = len(delta)
    both = np.concatenate([V, step_speed])
    if np.all(both == both[0]):
        speeds, inverse = both[:1], np.zeros(2 * n, dtype=np.int64)
    elif speed_tolerance > 0:
        speeds, inverse = geometric_levels(both, speed_tolerance)
    else:
        speeds, inverse = np.unique(both, return_inverse=True)
    theta = theta.to_vector() if isinstance(theta, Parameters) else np.asarray(theta, dtype=float)
    form = modal_form(theta[None, :], speeds, known, dt, intersample=kind)
    m = -(-n // every)
    states, out = np.empty((m, N_STATES)), np.empty((m, form.C.shape[-2]))
    step_level, out_level = (np.ascontiguousarray(i, dtype=np.int64) for i in (inverse[n:], inverse[:n]))
    input_recursion(*(np.ascontiguousarray(M[0]) for M in (form.Ad, form.Gamma, form.C, form.D[..., 0])),
                    step_level, out_level, np.ascontiguousarray(W), np.ascontiguousarray(delta), every, x, states, out)
    out[:, VY] = V[::every] * states[:, BETA]  # (v_y = V β at the sample's own speed, not its level's)
    return states, out


def simulate(vehicle: Vehicle, theta: Parameters, *, duration_s: float = 60.0, rate_hz: float = 1000.0,
             speed_mps=80 / 3.6, maneuver: str = "chirp", amplitude_rad: float = np.deg2rad(22.0),
             noise: SensorNoise | None = None, seed: int | None = 0, frequency_hz: float = 0.2,
             truth_name: str | None = None, effects=(),
             integration_rate_hz: float | None = INTEGRATION_RATE_HZ, lateral_velocity: bool = False,
             longitudinal_acceleration: bool = False) -> Simulation:
    """Simulate a test run of ``vehicle`` with true parameters ``theta``, logged at ``rate_hz``.

    ``speed_mps`` is a constant, an array of one speed per logged sample [m/s] or a
    :class:`~online_id.sim.maneuvers.SpeedProfile` (braking and traction; evaluated at the fine times when
    integrated finer than logged);
    ``maneuver`` is ``"chirp"`` (0.2-4 Hz sweep), ``"step"`` or ``"sine"``
    (at ``frequency_hz``); ``amplitude_rad`` is the steering-wheel amplitude.
    ``noise`` defaults to :class:`SensorNoise` (pass ``SensorNoise.none()`` for exact data), added to the
    logged samples.
    ``effects`` are unmodelled effects (:mod:`online_id.effects`) the simulated car and sensors
    have; a force law is solved step by step (the reference method) at the logged rate, by the whole-signal
    fixed point (to 1e-9 of the forces) at a finer one.
    ``integration_rate_hz``: integrate the car at ⌈integration_rate_hz / rate_hz⌉ sub-steps a logged sample
    (the module docstring: the cubic input between the fine samples, the speed interpolated linearly between the
    logged ones); None, or a rate not above ``rate_hz``, at the logged rate with the steering held
    (default :data:`INTEGRATION_RATE_HZ`).
    ``lateral_velocity``: the car also logs its lateral velocity at the centre of gravity, v_y = V β (an optical
    sideslip sensor's or an INS's, with ``noise.lateral_velocity``; issue 38). Its noise is drawn after the other
    channels', which are the same with it or without.
    ``longitudinal_acceleration``: the car also logs its longitudinal acceleration at the centre of gravity, as a
    body-fixed accelerometer reads it: a_x = dV/dt − v_y r [m/s²] (dV/dt the profile's exact derivative, or the
    logged speeds' central difference for an array), with ``noise.longitudinal_acceleration``, drawn after every
    other channel's. The lateral model itself schedules its matrices on V and has no V̇ term (MODEL.md).
    """
    if duration_s <= 0 or rate_hz <= 0:
        raise ValueError("duration and rate must be positive")
    noise = SensorNoise() if noise is None else noise
    n = int(round(duration_s * rate_hz))
    dt = 1.0 / rate_hz
    time = np.arange(n) * dt
    if maneuver not in maneuvers.MANEUVERS:
        raise ValueError(f"unknown maneuver {maneuver!r}; choose from {', '.join(maneuvers.MANEUVERS)}")
    profile = speed_mps if isinstance(speed_mps, SpeedProfile) else None
    V = profile.speed(time) if profile is not None else np.broadcast_to(np.asarray(speed_mps, dtype=float),
                                                                          (n,)).copy()
    if np.any(V <= 0):
        raise ValueError("the simulator needs a positive speed at every sample")
    k = sub_steps(rate_hz, integration_rate_hz)
    if k == 1:
        dH = _steering(maneuver, time, amplitude_rad, duration_s, frequency_hz)
        if effects:
            for e in effects:
                dH = e.logged_steering(dH, dt)
            states, out = _predict_moving_loads(
                lambda ax: predict(theta.to_vector(), effects, vehicle.known, dH, V, dt, method="loop",
                                   longitudinal_acceleration=ax), effects, V,
                profile.acceleration(time) if profile is not None else speed_slope(V, time))
        else:
            states, out = propagate(theta, vehicle.known, dH, V, dt)
    else:
        dH, states, out = _simulate_finely(vehicle, theta, time, k, V, effects,
                                           lambda t: _steering(maneuver, t, amplitude_rad, duration_s, frequency_hz),
                                           None if profile is None else profile.speed,
                                           None if profile is None else profile.acceleration)

    rng = np.random.default_rng(seed)
    noisy = out[:, :4] + rng.standard_normal((n, 4)) * np.array(
        [noise.yaw_rate, noise.roll_angle, noise.roll_rate, noise.lateral_acceleration])
    vy = out[:, 4] + rng.standard_normal(n) * noise.lateral_velocity if lateral_velocity else None
    ax = None
    if longitudinal_acceleration:
        dV = (profile.acceleration(time) if profile is not None
              else np.gradient(V, time) if n > 1 and not np.all(V == V[0]) else np.zeros(n))
        ax = dV - V * states[:, BETA] * states[:, R] + rng.standard_normal(n) * noise.longitudinal_acceleration
    meta = {
        "simulated": True,
        "vehicle": vehicle.name,
        "truth_name": truth_name,
        "truth": theta.to_dict(),
        "maneuver": maneuver,
        "amplitude_rad": float(amplitude_rad),
        "speed_mps": float(V[0]) if np.all(V == V[0]) else "varying",
        **({"speed_profile": profile.to_dict()} if profile is not None else {}),
        "duration_s": float(duration_s),
        "rate_hz": float(rate_hz),
        "noise": asdict(noise),
        "seed": seed,
        "effects": [e.to_dict() for e in effects],
    }
    if k > 1:  # (only then: a run logged at the rate it was integrated at keeps its sidecar as before)
        meta["integration_rate_hz"] = float(k * rate_hz)
    run = TrackRun(
        time=time,
        steering_wheel_angle=dH,
        speed=V,
        yaw_rate=noisy[:, 0],
        lateral_acceleration=noisy[:, 3],
        roll_angle=noisy[:, 1],
        roll_rate=noisy[:, 2],
        lateral_velocity=vy,
        longitudinal_acceleration=ax,
        source="simulation",
        meta=meta,
    )
    return Simulation(run=run, states=states, outputs=out)


def sub_steps(rate_hz: float, integration_rate_hz: float | None) -> int:
    """Fine samples a logged sample when integrating at ``integration_rate_hz`` (1: at the logged rate)."""
    if integration_rate_hz is None or integration_rate_hz <= rate_hz:
        return 1
    return int(np.ceil(integration_rate_hz / rate_hz - 1e-9))  # (10 kHz / 1 kHz is 10, whatever the rounding)


def _steering(maneuver: str, time, amplitude_rad: float, duration_s: float, frequency_hz: float) -> np.ndarray:
    """The steering-wheel angle [rad] of ``maneuver`` at ``time`` [s]."""
    if maneuver == "chirp":
        return maneuvers.chirp(time, amplitude_rad, duration_s=duration_s)
    if maneuver == "step":
        return maneuvers.step(time, amplitude_rad)
    return maneuvers.sine(time, amplitude_rad, frequency_hz)


def _simulate_finely(vehicle: Vehicle, theta: Parameters, time: np.ndarray, k: int, V: np.ndarray, effects,
                     steering, speed_at=None, acceleration_at=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The logged steering (n,), the states (n, 6) and the noise-free logged outputs (n, 4) at the logged
    ``time`` (n,) of the car integrated at k fine samples a logged sample (module docstring). ``V`` (n,) the
    speed at the logged samples [m/s]; ``steering`` the manoeuvre, a function of time [s]; ``speed_at`` the
    speed's, when known between the logged samples (a :class:`~online_id.sim.maneuvers.SpeedProfile`; else
    interpolated linearly); ``acceleration_at`` its dV/dt (else the interpolated speed's slope)."""
    n = len(time)
    dt = (time[1] - time[0]) / k if n > 1 else 1.0 / k
    fine_time = time[0] + np.arange((n - 1) * k + 1) * dt  # logged sample i is fine sample i·k,
    fine_time[::k] = time  # at the logged time itself (the manoeuvre logged as at the logged rate, to the bit)
    dH = steering(fine_time)  # (60 s at 10 kHz: 5 MB a signal)
    constant = bool(np.all(V == V[0]))
    speed = (np.full(len(fine_time), V[0]) if constant else np.interp(fine_time, time, V) if speed_at is None
             else speed_at(fine_time))
    tolerance = 0.0 if constant else FINE_SPEED_TOLERANCE
    if not effects:  # (in chunks: the fine arrays of a long run would take 120 bytes a fine sample)
        states, out = _propagate_finely(theta, vehicle.known, fine_time, dH, speed, dt, k, tolerance)
        return dH[::k], states, out
    for e in effects:
        dH = e.logged_steering(dH, dt)
    effects = in_stage_order(effects)
    if has_force_law(effects, theta.to_vector(), vehicle.known):
        hold = max(1, int(round(FINE_FORCE_BLOCK_S / dt)))
        dV = speed_slope(speed, fine_time) if acceleration_at is None else acceleration_at(fine_time)
        states, out = _predict_moving_loads(
            lambda ax: predict(theta.to_vector(), effects, vehicle.known, dH, speed, dt, method="midpoint",
                               intersample="cubic", hold=hold, longitudinal_acceleration=ax), effects, speed, dV)
    else:  # the linear model's compiled exact steps (predict's would take each fine sample's modal form)
        steering, th = car_inputs(effects, dH, theta.to_vector(), vehicle.known, dt)
        states, out = propagate(th, vehicle.known, steering, speed, dt, intersample="cubic",
                                speed_tolerance=tolerance)
        out = logged_outputs(effects, out, dt, speed)
    return dH[::k], states[::k], out[::k]


def _predict_moving_loads(run_model, effects, speed, dV):
    """States and outputs of ``run_model(longitudinal_acceleration)``: once with a_x = dV/dt when no effect moves
    the axle loads with it; else twice, the second time with the body-fixed a_x = dV/dt − V·β·r of the first
    (the acceleration the CG feels, and the logged ``longitudinal_acceleration``): the loads then lag the state
    by one pass, a change in β·r of second order."""
    states, out = run_model(dV)
    if any(e.moves_loads for e in effects):
        states, out = run_model(dV - np.asarray(speed, dtype=float) * states[:, BETA] * states[:, R])
    return states, out


def _propagate_finely(theta, known, time, steering, speed, dt: float, k: int, tolerance: float):
    """States (n, 6) and outputs (n, 4) at every k-th of the fine samples (``time``, ``steering``, ``speed``: (N,),
    N = (n − 1)k + 1), the cubic between them: :func:`propagate`, a chunk of :data:`FINE_CHUNK` fine samples at a
    time, each from the state the last ended at, its step inputs from the samples around it (the same numbers)."""
    N = len(time)
    delta = steering / known.steering_ratio
    per = max(1, FINE_CHUNK // k) * k  # fine samples a chunk moves on: a whole number of logged samples
    x = np.zeros(N_STATES)
    states, out = [], []
    for a in range(0, N, per):
        b = min(a + per, N - 1)  # the chunk's last fine sample, a logged one (the next chunk's first)
        lo, hi = max(a - 2, 0), min(b + 2, N)  # two samples before, one after: the slopes at the chunk's ends
        W, step_speed = step_inputs("cubic", delta[lo:hi], speed[lo:hi], dt)
        own = slice(a - lo, a - lo + b - a + 1)
        s, y = _propagate_inputs(theta, known, delta[a:b + 1], speed[a:b + 1], W[own], step_speed[own], dt, x,
                                 "cubic", k, tolerance)
        x = s[-1]
        last = b == N - 1
        states.append(s if last else s[:-1])
        out.append(y if last else y[:-1])
        if last:
            break
    return np.concatenate(states), np.concatenate(out)
