"""An independent simulator written by others: CommonRoad's multibody vehicle model (``vehiclemodels``,
PyPI ``commonroad-vehicle-models``, test extra only) driven through online-id's test protocols.

``vehicle_dynamics_mb`` has 29 states: sprung mass with roll, pitch and heave, two unsprung axles
with their own roll and lateral motion, four wheel spins, Pacejka magic-formula tyres with camber
and combined slip, lateral compliance. Its three cars: 1 Ford Escort, 2 BMW 320i, 3 VW Vanagon.
It is not Haro's model: this is a car online-id has never seen.

:func:`simulate_mb` integrates it with fixed-step RK4 (the step = the sample period) and writes a
track run in ISO 8855 signs: steering-wheel angle = road-wheel angle × :data:`STEERING_RATIO`;
lateral acceleration at the whole car's centre of mass, Σ m_i·(v̇_y,i + r·v_x) / m over the sprung
mass and both unsprung axles (the total lateral force over the total mass, as a_y = V(β̇ + r) of the
single-track model); roll angle and rate of the sprung mass, sign turned to ISO 8855 (:data:`ROLL_SIGN`);
white sensor noise as the built-in runs.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np

from online_id.io.tracklog import TrackRun
from online_id.sim import maneuvers
from online_id.sim.simulator import SensorNoise
from online_id.vehicle.loader import Vehicle, parse_vehicle
from online_id.vehicle.parameters import Parameters

#: Steering-wheel over road-wheel angle written to the logs (the MB model steers the road wheels).
STEERING_RATIO = 16.0
#: CommonRoad limits the road-wheel rate to 0.4 rad/s (an automated-driving actuator); a hand-driven
#: 4 Hz chirp exceeds it, so the harness lifts the limit [rad/s].
STEERING_RATE_LIMIT = 10.0
#: Proportional gain of the speed hold through the longitudinal-acceleration input [1/s].
SPEED_HOLD_GAIN = 2.0
G = 9.81  # m/s², the MB model's own gravity
#: The MB model's roll angle (state x7) is negative in a left turn: against V·r its slope is about
#: −9 deg/g on all three cars (found by the ``roll`` plausibility check). ISO 8855 rolls a left turn
#: to positive φ, so the harness logs −x7 and −x8.
ROLL_SIGN = -1.0
CAR_NAMES = {1: "Ford Escort", 2: "BMW 320i", 3: "VW Vanagon"}


def mb_parameters(car: int):
    """The package's parameter set of car 1, 2 or 3, with the steering-rate limit lifted."""
    from vehiclemodels.vehicle_parameters import setup_vehicle_parameters

    p = copy.deepcopy(setup_vehicle_parameters(vehicle_id=car))
    p.steering.v_max, p.steering.v_min = STEERING_RATE_LIMIT, -STEERING_RATE_LIMIT
    return p


def steering_input(maneuver: str, time: np.ndarray, amplitude_rad: float) -> np.ndarray:
    """Steering-wheel angle [rad] at ``time``: ``chirp`` (Haro's 0.2-4 Hz), ``steps`` (alternating
    steps every 3 s, 0.2 s ramps) or ``sines`` (0.4 Hz plus 1.7 Hz at half the amplitude)."""
    if maneuver == "chirp":
        return maneuvers.chirp(time, amplitude_rad, duration_s=float(time[-1]))
    if maneuver == "steps":
        level = np.where((time // 3.0) % 2 == 0, 1.0, -1.0) * (time >= 1.0)
        ramp = int(round(0.2 / (time[1] - time[0])))
        return amplitude_rad * np.convolve(level, np.ones(ramp) / ramp, mode="full")[: len(time)]
    if maneuver == "sines":
        return 0.67 * amplitude_rad * (np.sin(2 * np.pi * 0.4 * time) + 0.5 * np.sin(2 * np.pi * 1.7 * time))
    raise ValueError(f"unknown manoeuvre {maneuver!r}")


def simulate_mb(car: int, maneuver: str = "chirp", *, speed_kmh: float = 80.0, duration_s: float = 30.0,
                rate_hz: float = 250.0, amplitude_deg: float = 22.0, noise: SensorNoise | None = None,
                seed: int = 0, lateral_velocity: bool = False) -> TrackRun:
    """A track run of CommonRoad car ``car`` (1, 2, 3) under ``maneuver`` at ``speed_kmh``; with
    ``lateral_velocity`` the lateral velocity of the whole car's centre of gravity logged too (the MB model's
    sprung and unsprung masses' lateral velocities, states 10, 15 and 20, mass-weighted as a_y is), its noise
    drawn after the other channels'."""
    from vehiclemodels.init_mb import init_mb
    from vehiclemodels.vehicle_dynamics_mb import vehicle_dynamics_mb

    p = mb_parameters(car)
    noise = SensorNoise() if noise is None else noise
    dt = 1.0 / rate_hz
    n = int(round(duration_s * rate_hz))
    time = np.arange(n) * dt
    dH = steering_input(maneuver, np.arange(n + 1) * dt, np.deg2rad(amplitude_deg))
    delta = dH / STEERING_RATIO
    V_ref = speed_kmh / 3.6
    x = np.array(init_mb([0, 0, 0, V_ref, 0, 0, 0], p), dtype=float)
    f = lambda x, u: np.array(vehicle_dynamics_mb(list(x), u, p))  # noqa: E731
    out = np.empty((n, 6))  # speed, yaw rate, a_y, roll, roll rate, lateral velocity
    m = p.m_s + p.m_uf + p.m_ur
    for k in range(n):
        u = [(delta[k + 1] - x[2]) / dt, SPEED_HOLD_GAIN * (V_ref - x[3])]
        k1 = f(x, u)
        r, vx = x[5], x[3]
        ay = (p.m_s * (k1[10] + r * vx) + p.m_uf * (k1[15] + r * vx) + p.m_ur * (k1[20] + r * vx)) / m
        vy = (p.m_s * x[10] + p.m_uf * x[15] + p.m_ur * x[20]) / m
        out[k] = (vx, r, ay, ROLL_SIGN * x[6], ROLL_SIGN * x[7], vy)
        k2 = f(x + 0.5 * dt * k1, u)
        k3 = f(x + 0.5 * dt * k2, u)
        k4 = f(x + dt * k3, u)
        x = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    rng = np.random.default_rng(seed)
    noisy = lambda v, s: v + rng.standard_normal(n) * s  # noqa: E731
    return TrackRun(
        time=time, steering_wheel_angle=dH[:n], speed=out[:, 0],
        yaw_rate=noisy(out[:, 1], noise.yaw_rate), lateral_acceleration=noisy(out[:, 2], noise.lateral_acceleration),
        roll_angle=noisy(out[:, 3], noise.roll_angle), roll_rate=noisy(out[:, 4], noise.roll_rate),
        lateral_velocity=noisy(out[:, 5], noise.lateral_velocity) if lateral_velocity else None,
        source=f"CommonRoad MB car {car} ({CAR_NAMES[car]}), {maneuver} at {speed_kmh:g} km/h",
        meta={"simulator": "commonroad-vehicle-models vehicle_dynamics_mb", "car": car, "maneuver": maneuver,
              "speed_kmh": speed_kmh, "amplitude_deg": amplitude_deg, "rate_hz": rate_hz, "seed": seed},
    )


@dataclass(frozen=True)
class Nominal:
    """The 8 parameters as the parameter file implies them (approximations, see :func:`nominal_parameters`)."""

    parameters: Parameters
    notes: str


def nominal_parameters(car: int) -> Nominal:
    """What Haro's 8 parameters would be for this car, from its parameter file.

    Mzz: sprung yaw inertia plus the unsprung masses at the axles; Mxx: sprung roll inertia;
    D1, D2: 2·p_ky1·F_z per axle at the static load (the magic formula's slope at zero slip);
    Kro: springs and anti-roll torsion in series with the tyres' vertical stiffness, less m_s·g·h_s
    (Haro's Kro is effective: no gravity moment); Aro: the dampers; b1, b2: the tyre's lateral
    compliance × its cornering stiffness (the relaxation a compliance gives).
    """
    p = mb_parameters(car)
    L = p.a + p.b
    fz = {1: (p.m_s * G * p.b / L + p.m_uf * G) / 2, 2: (p.m_s * G * p.a / L + p.m_ur * G) / 2}
    ky = {i: abs(p.tire.p_ky1) * fz[i] for i in fz}
    roll = []
    for K_s, K_ts, T in ((p.K_sf, p.K_tsf, p.T_f), (p.K_sr, p.K_tsr, p.T_r)):
        spring = 0.5 * K_s * T**2 - K_ts
        tyre = 0.5 * p.K_zt * T**2
        roll.append(spring * tyre / (spring + tyre))
    theta = Parameters(
        Mzz=p.I_z + p.m_uf * p.a**2 + p.m_ur * p.b**2, Mxx=p.I_Phi_s, D1=2 * ky[1], D2=2 * ky[2],
        Aro=0.5 * (p.K_sdf * p.T_f**2 + p.K_sdr * p.T_r**2), Kro=sum(roll) - p.m_s * G * p.h_s,
        b1=ky[1] * p.K_lt, b2=ky[2] * p.K_lt)
    return Nominal(theta, "derived from the MB parameter file; Kro and b are approximate")


def vehicle_for(car: int) -> Vehicle:
    """An online-id vehicle for CommonRoad car ``car``: mass, axle positions and heights from its
    parameter file; the prior of the 8 parameters scaled from haro2008's constructor values (not the
    nominal values above), with 100 % relative σ."""
    p = mb_parameters(car)
    L = p.a + p.b
    scale = p.m_s / 1262.0  # haro2008's sprung mass
    front_load, rear_load = p.m * G * p.b / L, p.m * G * p.a / L
    roll_axis = (p.h_raf * p.b + p.h_rar * p.a) / L
    text = f"""
name = "commonroad_mb_{car}"
description = "CommonRoad MB car {car} ({CAR_NAMES[car]}): masses, axles, heights from its parameter file"
steering_ratio = {STEERING_RATIO}
[known]
M = {p.m}
ms = {p.m_s}
Mxz = {p.I_xz_s}
h0 = {p.h_s - roll_axis}
h1 = {p.h_raf}
h2 = {p.h_rar}
hg = {p.h_cg}
l1 = {p.a}
l2 = {p.b}
eps1 = 0.0
eps2 = 0.0
[prior]
Mzz = {0.9 * p.m * p.a * p.b}
Mxx = {252.0 * scale}
D1 = {12.0 * front_load}
D2 = {14.0 * rear_load}
Aro = {2750.0 * scale}
Kro = {150000.0 * scale}
b1 = 0.5
b2 = 0.5
[prior_relative_std]
Mzz = 1.0
Mxx = 1.0
D1 = 1.0
D2 = 1.0
Aro = 1.0
Kro = 1.0
b1 = 1.0
b2 = 1.0
"""
    return parse_vehicle(text, source=f"CommonRoad MB car {car}")
