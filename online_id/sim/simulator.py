"""Simulated track runs: the lateral model driven by a steering input, plus sensor noise.

The model is advanced with its exact zero-order-hold discretisation, the
speed scheduled sample by sample (one discretisation per distinct speed); the recursion is compiled
(:func:`online_id.sim.block_loop.sample_recursion`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from online_id.io.tracklog import TrackRun
from online_id.model.discretise import discretise_continuous
from online_id.model.lateral import BETA, N_STATES, continuous_matrices, outputs_from_continuous
from online_id.sim import maneuvers
from online_id.sim.with_effects import predict
from online_id.vehicle.loader import Vehicle
from online_id.vehicle.parameters import Parameters


@dataclass(frozen=True)
class SensorNoise:
    """Standard deviation of white sensor noise per channel (SI units). Zero means exact."""

    yaw_rate: float = 0.004              # rad/s
    lateral_acceleration: float = 0.05   # m/s²
    roll_angle: float = 0.0005           # rad
    roll_rate: float = 0.004             # rad/s

    @classmethod
    def none(cls) -> SensorNoise:
        return cls(0.0, 0.0, 0.0, 0.0)


@dataclass
class Simulation:
    """Noise-free states and outputs of a simulation, with the run as logged.

    Attributes
    ----------
    run : the logged run (outputs with noise)
    states : (N, 6) model states [r, β, φ, p, α1, α2]
    outputs : (N, 4) noise-free outputs [r, φ, p, a_y]
    """

    run: TrackRun
    states: np.ndarray
    outputs: np.ndarray


def propagate(theta, known, steering_wheel_angle, speed, dt: float, x0=None):
    """States (N, 6) and noise-free outputs (N, 4) for the given inputs.

    ``steering_wheel_angle`` [rad] and ``speed`` [m/s] have shape (N,) (speed
    may be a scalar); the input is held constant over each period ``dt`` [s].
    """
    dH = np.asarray(steering_wheel_angle, dtype=float)
    n = len(dH)
    V = np.broadcast_to(np.asarray(speed, dtype=float), (n,))
    delta = dH / known.steering_ratio
    x = np.zeros(N_STATES) if x0 is None else np.asarray(x0, dtype=float).copy()
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


def simulate(vehicle: Vehicle, theta: Parameters, *, duration_s: float = 60.0, rate_hz: float = 1000.0,
             speed_mps=80 / 3.6, maneuver: str = "chirp", amplitude_rad: float = np.deg2rad(22.0),
             noise: SensorNoise | None = None, seed: int | None = 0, frequency_hz: float = 0.2,
             truth_name: str | None = None, effects=()) -> Simulation:
    """Simulate a test run of ``vehicle`` with true parameters ``theta``.

    ``speed_mps`` is a constant or an array of one speed per sample [m/s];
    ``maneuver`` is ``"chirp"`` (0.2-4 Hz sweep), ``"step"`` or ``"sine"``
    (at ``frequency_hz``); ``amplitude_rad`` is the steering-wheel amplitude.
    ``noise`` defaults to :class:`SensorNoise` (pass ``SensorNoise.none()`` for exact data).
    ``effects`` are unmodelled effects (:mod:`online_id.effects`) the simulated car and sensors
    have; a force law is solved step by step (the reference method).
    """
    if duration_s <= 0 or rate_hz <= 0:
        raise ValueError("duration and rate must be positive")
    noise = SensorNoise() if noise is None else noise
    n = int(round(duration_s * rate_hz))
    dt = 1.0 / rate_hz
    time = np.arange(n) * dt
    if maneuver == "chirp":
        dH = maneuvers.chirp(time, amplitude_rad, duration_s=duration_s)
    elif maneuver == "step":
        dH = maneuvers.step(time, amplitude_rad)
    elif maneuver == "sine":
        dH = maneuvers.sine(time, amplitude_rad, frequency_hz)
    else:
        raise ValueError(f"unknown maneuver {maneuver!r}; choose from {', '.join(maneuvers.MANEUVERS)}")
    V = np.broadcast_to(np.asarray(speed_mps, dtype=float), (n,)).copy()
    if np.any(V <= 0):
        raise ValueError("the simulator needs a positive speed at every sample")
    if effects:
        for e in effects:
            dH = e.logged_steering(dH, dt)
        states, out = predict(theta.to_vector(), effects, vehicle.known, dH, V, dt, method="loop")
    else:
        states, out = propagate(theta, vehicle.known, dH, V, dt)

    rng = np.random.default_rng(seed)
    noisy = out + rng.standard_normal(out.shape) * np.array(
        [noise.yaw_rate, noise.roll_angle, noise.roll_rate, noise.lateral_acceleration])
    meta = {
        "simulated": True,
        "vehicle": vehicle.name,
        "truth_name": truth_name,
        "truth": theta.to_dict(),
        "maneuver": maneuver,
        "amplitude_rad": float(amplitude_rad),
        "speed_mps": float(V[0]) if np.all(V == V[0]) else "varying",
        "duration_s": float(duration_s),
        "rate_hz": float(rate_hz),
        "noise": asdict(noise),
        "seed": seed,
        "effects": [e.to_dict() for e in effects],
    }
    run = TrackRun(
        time=time,
        steering_wheel_angle=dH,
        speed=V,
        yaw_rate=noisy[:, 0],
        lateral_acceleration=noisy[:, 3],
        roll_angle=noisy[:, 1],
        roll_rate=noisy[:, 2],
        lateral_velocity=V * np.tan(states[:, BETA]),
        source="simulation",
        meta=meta,
    )
    return Simulation(run=run, states=states, outputs=out)
