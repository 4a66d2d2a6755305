"""What the race car's lateral kinematics leave over, lap by lap (docs/measured.md, "What the race line still
misses: the track's bank"): the slow part of v̇_y + V·r − a_y, which on a level road is zero whatever the tyres do.

The accelerometer measures the tyres' force over the mass (specific force); the INS's lateral velocity follows the
whole acceleration, gravity's lateral component included. Their difference, v̇_y + V·r − a_y, is g·sin(bank) on a
banked road (and the sensors' errors). No tyre law or sensor effect of the model can produce it, so it bounds what
the diagnosis can still explain. This script prints its size, how much of it a_y or a_x explains (a roll-induced
gravity term or a misaligned accelerometer would be proportional to them), and its value along each lap (lap
distance from ∫V dt, the lap length from the yaw rate's autocorrelation over distance): if the same shape comes
back lap after lap, the road is banked.

Run: python benchmarks/race_bank.py   (a few seconds)
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.signal import savgol_filter

from online_id.io.tracklog import read_track_run

RACE = Path(__file__).resolve().parents[1] / ".." / "shared" / "realdata" / "revs_250lm" / "revs_250lm_laps_0-400s.csv"
MISALIGNMENT = 0.0021  # rad, the INS's (diagnose)
SLOW_S = 3.01  # s, the window of the slow part (a bank changes over tens of metres, ~1 s at 40 m/s)
POINTS_PER_LAP = 20


def main() -> None:
    run = read_track_run(RACE)
    t = np.asarray(run.time, dtype=float)
    dt = float(np.median(np.diff(t)))
    V = np.asarray(run.speed, dtype=float)
    r = savgol_filter(np.asarray(run.yaw_rate, dtype=float), 51, 3)
    ay = savgol_filter(np.asarray(run.lateral_acceleration, dtype=float), 51, 3)
    vy = np.asarray(run.lateral_velocity, dtype=float) - MISALIGNMENT * V
    vy_dot = savgol_filter(vy, 51, 3, deriv=1, delta=dt)
    residual = vy_dot + V * r - ay
    window = int(round(SLOW_S / dt)) | 1
    slow = savgol_filter(residual, window, 2)

    print("v̇_y + V·r − a_y [m/s²]  (zero on a level road, g·sin(bank) on a banked one)")
    for lo, hi in ((0.0, 400.0), (0.0, 300.0), (300.0, 400.0)):
        m = (t >= lo) & (t < hi)
        print(f"  {lo:3.0f}-{hi:3.0f} s: mean {residual[m].mean():+.3f}, RMS about it {residual[m].std():.3f}, "
              f"its slow part ({SLOW_S:g} s) {slow[m].std():.3f}")

    ay_slow = savgol_filter(np.asarray(run.lateral_acceleration, dtype=float), window, 2)
    ax_slow = savgol_filter(np.asarray(run.longitudinal_acceleration, dtype=float), window, 2)
    print("\nthe slow part regressed on what a sensor effect would make it proportional to")
    for label, columns in (("a_y", [ay_slow]), ("a_x", [ax_slow]), ("a_y and a_x", [ay_slow, ax_slow])):
        X = np.column_stack([*columns, np.ones_like(slow)])
        coef, *_ = np.linalg.lstsq(X, slow, rcond=None)
        left = slow - X @ coef
        print(f"  {label:12s} coefficients {np.round(coef[:-1], 4)}: RMS left {left.std():.3f} of {slow.std():.3f}")

    distance = np.cumsum(V) * dt
    grid = np.arange(0.0, distance[-1], 1.0)
    curvature = np.interp(grid, distance, r) - r.mean()
    ac = np.correlate(curvature, curvature, "full")[len(curvature) - 1:]
    ac /= ac[0]
    lap = int(np.argmax(ac[1000:6000])) + 1000
    print(f"\nlap length from the yaw rate's autocorrelation over distance: {lap} m (correlation {ac[lap]:.2f})")
    on_grid = np.interp(grid, distance, slow)
    step = lap // POINTS_PER_LAP
    print(f"the slow part along each lap, every {step} m [m/s²]:")
    laps = []
    for k in range(len(grid) // lap):
        row = on_grid[k * lap:(k + 1) * lap:step][:POINTS_PER_LAP]
        laps.append(row)
        print(f"  lap {k}: " + " ".join(f"{v:+.2f}" for v in row))
    laps = np.array(laps)
    mean = laps.mean(axis=0)
    print("  mean : " + " ".join(f"{v:+.2f}" for v in mean))
    print(f"the lap mean's RMS {mean.std():.3f}; each lap about the mean {np.sqrt(np.mean((laps - mean) ** 2)):.3f} "
          f"(a track-fixed term: the first well above the second); as a bank angle, up to "
          f"{np.degrees(np.arcsin(np.abs(mean).max() / 9.81)):.1f}°")


if __name__ == "__main__":
    main()
