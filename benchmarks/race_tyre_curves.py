"""The race car's axle forces against their slip angles, by the longitudinal acceleration (docs/measured.md, "The race
car's tyres follow their load"): what showed that its cornering stiffness moves with the load and the braking or
driving force, which the peak-only laws (load_transfer, combined_slip) hold static.

Equation error, not the tool's fits: each axle's lateral force from the logged a_y and ṙ (F1 = (M·a_y·l2 + Mzz·ṙ)/L,
F2 = (M·a_y·l1 − Mzz·ṙ)/L, Savitzky-Golay smoothed over 0.21 s, Mzz 1,035 kg·m² from the polish) against its slip
angle from the INS's lateral velocity (its 0.0021 rad misalignment removed), the road-wheel angle and the yaw rate.
Prints the mean |F|/Fz⁰ by slip-angle band and a_x band, then each tyre law fitted to the forces of 0-300 s and its
RMS error on 300-400 s.

Run: python benchmarks/race_tyre_curves.py   (a few seconds)
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.optimize import least_squares
from scipy.signal import savgol_filter

from online_id.io.tracklog import read_track_run
from online_id.vehicle import load_vehicle

RACE = Path(__file__).resolve().parents[1] / ".." / "shared" / "realdata" / "revs_250lm" / "revs_250lm_laps_0-400s.csv"
MZZ = 1035.0  # kg·m², the polished estimate
MISALIGNMENT = 0.0021  # rad, the INS's (diagnose)
BANDS = (("braking > 0.4 g", -np.inf, -4.0), ("braking 0.15-0.4 g", -4.0, -1.5), ("coasting", -1.5, 0.5),
         ("traction < 0.25 g", 0.5, 2.5), ("traction > 0.25 g", 2.5, np.inf))
SLIP_EDGES = (0.005, 0.015, 0.025, 0.035, 0.05, 0.07, 0.1)


def main() -> None:
    car = load_vehicle("revs_250lm")
    k = car.known
    run = read_track_run(RACE)
    dt = float(np.median(np.diff(run.time)))
    L, g = k.l1 + k.l2, 9.81

    def smooth(x):
        return savgol_filter(np.asarray(x, dtype=float), 21, 3)

    V = np.asarray(run.speed, dtype=float)
    r = smooth(run.yaw_rate)
    r_dot = savgol_filter(np.asarray(run.yaw_rate, dtype=float), 21, 3, deriv=1, delta=dt)
    ay = smooth(run.lateral_acceleration)
    vy = smooth(run.lateral_velocity) - MISALIGNMENT * V
    ax = smooth(run.longitudinal_acceleration)
    delta = smooth(run.steering_wheel_angle) / k.steering_ratio
    forces = ((k.M * ay * k.l2 + MZZ * r_dot) / L, (k.M * ay * k.l1 - MZZ * r_dot) / L)
    slips = (delta - (vy + k.l1 * r) / V, -(vy - k.l2 * r) / V)
    static = np.array([k.M * g * k.l2 / L, k.M * g * k.l1 / L])
    loads = (k.M * (g * k.l2 - ax * k.hg) / L, k.M * (g * k.l1 + ax * k.hg) / L)
    front_share = np.where(ax < 0, k.brake_front_share, k.drive_front_share)
    long_forces = (front_share * k.M * ax, (1 - front_share) * k.M * ax)
    moving = V > 15.0

    print("mean |F|/Fz0 by slip-angle band [rad] (samples) and a_x band")
    for axle, name in enumerate(("front", "rear")):
        F, a = forces[axle], slips[axle]
        print(f"{name}: " + "  ".join(f"{lo:.3f}-{hi:.3f}" for lo, hi in zip(SLIP_EDGES[:-1], SLIP_EDGES[1:])))
        for label, lo, hi in BANDS:
            band = moving & (ax > lo) & (ax <= hi)
            cells = []
            for s_lo, s_hi in zip(SLIP_EDGES[:-1], SLIP_EDGES[1:]):
                m = band & (np.abs(a) >= s_lo) & (np.abs(a) < s_hi)
                cells.append(f"{np.mean(F[m] * np.sign(a[m])) / static[axle]:6.3f} ({m.sum():4d})" if m.sum() > 20
                             else "     -       ")
            print(f"  {label:20s}" + " ".join(cells))

    t = np.asarray(run.time, dtype=float)
    train, held = moving & (t < 300), moving & (t >= 300)

    def law(p, kind, axle):
        D, mu = np.exp(p[0]), p[1]
        a, Fz, Fz0, Fx = slips[axle], loads[axle], static[axle], long_forces[axle]
        if kind == "static loads":
            peak = mu * Fz0
            return peak * np.tanh(D * a / peak)
        if kind == "peak moved (load_transfer)":
            peak = mu * Fz
            return peak * np.tanh(D * a / peak)
        if kind == "peak on the ellipse (combined_slip)":
            peak = np.sqrt(np.maximum((mu * Fz) ** 2 - Fx ** 2, (0.2 * mu * Fz) ** 2))
            return peak * np.tanh(D * a / peak)
        exponent = 1.0 if kind == "whole curve ∝ load × ellipse" else p[2]
        scale = (Fz / Fz0) ** exponent
        share = np.sqrt(np.maximum(1 - (Fx / (scale * mu * Fz0)) ** 2, 0.04))
        return scale * share * mu * Fz0 * np.tanh(D * a / (mu * Fz0))

    kinds = ("static loads", "peak moved (load_transfer)", "peak on the ellipse (combined_slip)",
             "whole curve ∝ load × ellipse", "whole curve ∝ load^p × ellipse (load_sensitivity)")
    print("\neach law fitted to 0-300 s, its RMS error on 300-400 s [N]")
    for axle, name in enumerate(("front", "rear")):
        for kind in kinds:
            start = [np.log(80000.0), 1.1] + ([1.0] if "^p" in kind else [])
            fit = least_squares(lambda p, kind=kind, axle=axle: (law(p, kind, axle) - forces[axle])[train], start)
            held_rms = np.sqrt(np.mean((law(fit.x, kind, axle) - forces[axle])[held] ** 2))
            extra = f", p {fit.x[2]:.2f}" if len(fit.x) > 2 else ""
            print(f"  {name} {kind:50s} {held_rms:6.1f} N (D {np.exp(fit.x[0]):.0f} N/rad, μ {fit.x[1]:.3f}{extra})")


if __name__ == "__main__":
    main()
