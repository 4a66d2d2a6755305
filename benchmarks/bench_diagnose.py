"""Diagnosis acceptance matrix: each effect at a moderate strength, none, and two at once.

For every case a 60 s, 1 kHz chirp run at 80 km/h (seed 1) is diagnosed against a validation run at
60 km/h (seed 2). Prints the verdict, the held-out reduction of the best candidate, its fitted
parameters and the wall time (the issue's budget: 5 minutes per diagnosis).

    python benchmarks/bench_diagnose.py [--duration 60] [--case tire_saturation=0.6 ...]
"""

from __future__ import annotations

import argparse
import time

from online_id.diagnosis.diagnose import diagnose
from online_id.effects import parse_effect
from online_id.sim.simulator import simulate
from online_id.vehicle.loader import load_vehicle

CASES = ["tire_saturation=0.6", "accelerometer_gravity=1", "sensor_delay=yaw_rate:0.03",
         "sensor_bias=lateral_acceleration:0.3", "sensor_bias=steering_wheel_angle:0.02",
         "steering_compliance=0.15", "none", "tire_saturation=0.6,sensor_delay=yaw_rate:0.03"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--case", action="append", help="comma-separated effects, or none (default: the matrix)")
    args = ap.parse_args()
    vehicle = load_vehicle("haro2008")
    truth = vehicle.truth("track")
    for case in args.case or CASES:
        effects = [] if case == "none" else [parse_effect(t) for t in case.split(",")]
        run = simulate(vehicle, truth, duration_s=args.duration, seed=1, effects=effects).run
        val = simulate(vehicle, truth, duration_s=args.duration, seed=2, speed_mps=60 / 3.6, effects=effects).run
        t0 = time.perf_counter()
        d = diagnose(vehicle, run, val)
        wall = time.perf_counter() - t0
        best = d.candidates[0]
        sig = ", ".join(f"{c.fit.label} {100 * c.reduction:.1f}%" for c in d.candidates if c.significant) or "none"
        params = ", ".join(f"{k}={v:.4g}" for e in best.fit.effects for k, v in e.values.items())
        combo = f"; together: {d.combination['label']} {100 * d.combination['reduction']:.1f}%" \
            if d.combination else ""
        print(f"{case:<50} verdict {str(d.verdict):<22} best {best.fit.label} {100 * best.reduction:5.1f}%"
              f" ({params}); significant: {sig}{combo}; {wall:.1f} s", flush=True)


if __name__ == "__main__":
    main()
