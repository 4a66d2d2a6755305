"""What the race car's lateral kinematics leave over, lap by lap (docs/measured.md, "What the race line still
misses: the track's bank"): the slow part of v̇_y + V·r − a_y, which on a level road is zero whatever the tyres do.

The accelerometer measures the tyres' force over the mass (specific force); the INS's lateral velocity follows the
whole acceleration, gravity's lateral component included. Their difference, v̇_y + V·r − a_y, is g·sin(bank) on a
banked road (and the sensors' errors). No tyre law or sensor effect of the model can produce it. This script takes
`diagnose`'s own measure of it (:func:`online_id.diagnosis.kinematics.slow_parts`: a 3 s moving mean, less what a
term in a_y, in dV/dt and a constant explain, as a tilted accelerometer, an INS turned in yaw or a bias would), prints
its size over the log and its halves, and its value along each lap (lap distance from ∫V dt, the lap length from the
yaw rate's autocorrelation over distance): if the same shape comes back lap after lap, the road is banked.

Run: python benchmarks/race_bank.py   (a few seconds)
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from online_id.diagnosis.kinematics import WINDOW_S, slow_parts
from online_id.io.tracklog import read_track_run

RACE = Path(__file__).resolve().parents[1] / ".." / "shared" / "realdata" / "revs_250lm" / "revs_250lm_laps_0-400s.csv"
POINTS_PER_LAP = 20


def main() -> None:
    run = read_track_run(RACE)
    t, V, r = (np.asarray(x, dtype=float) for x in (run.time, run.speed, run.yaw_rate))
    times, part, left, coef = slow_parts(t, V, np.asarray(run.lateral_velocity, dtype=float),
                                         np.asarray(run.lateral_acceleration, dtype=float), r)
    print(f"v̇_y + V·r − a_y [m/s²], its slow part ({WINDOW_S:g} s moving mean; zero on a level road, g·sin(bank) on a"
          f" banked one); a_y coefficient {coef[0]:+.4f}, dV/dt {coef[1]:+.4f}, constant {coef[2]:+.3f} m/s²")
    for lo, hi in ((0.0, 400.0), (0.0, 300.0), (300.0, 400.0)):
        m = (times >= lo) & (times < hi)
        print(f"  {lo:3.0f}-{hi:3.0f} s: slow part {part[m].std():.3f} RMS about its mean {part[m].mean():+.3f}; what"
              f" a_y, dV/dt and a constant leave {np.sqrt(np.mean(left[m] ** 2)):.3f} RMS")

    distance = np.cumsum(V) * float(np.median(np.diff(t)))
    grid = np.arange(0.0, distance[-1], 1.0)
    curvature = np.interp(grid, distance, r) - r.mean()
    ac = np.correlate(curvature, curvature, "full")[len(curvature) - 1:]
    ac /= ac[0]
    lap = int(np.argmax(ac[1000:6000])) + 1000
    print(f"\nlap length from the yaw rate's autocorrelation over distance: {lap} m (correlation {ac[lap]:.2f})")
    on_grid = np.interp(grid, np.interp(times, t, distance), left, left=np.nan, right=np.nan)
    step = lap // POINTS_PER_LAP
    print(f"what is left along each lap, every {step} m [m/s²] (nan: the log's first and last {WINDOW_S / 2:g} s):")
    laps = []
    for k in range(len(grid) // lap):
        row = on_grid[k * lap:(k + 1) * lap:step][:POINTS_PER_LAP]
        laps.append(row)
        print(f"  lap {k}: " + " ".join(f"{v:+.2f}" for v in row))
    laps = np.array(laps)
    mean = np.nanmean(laps, axis=0)
    print("  mean : " + " ".join(f"{v:+.2f}" for v in mean))
    print(f"the lap mean's RMS {np.sqrt(np.mean(mean ** 2)):.3f}; each lap about the mean"
          f" {np.sqrt(np.nanmean((laps - mean) ** 2)):.3f} (a track-fixed term: the first well above the second); as a"
          f" bank angle, up to {np.degrees(np.arcsin(np.abs(mean).max() / 9.81)):.1f}°")


if __name__ == "__main__":
    main()
