"""Diagnosis acceptance matrix: each effect at a moderate strength, none, and two at once.

For every case a 60 s, 1 kHz chirp run at 80 km/h (seed 1) is diagnosed against a validation run at
60 km/h (seed 2). Prints the verdict, the held-out reduction of the best candidate, its fitted
parameters and the wall time (the issue's budget: 5 minutes per diagnosis).

    python benchmarks/bench_diagnose.py [--duration 60] [--case tire_saturation=0.6 ...]
    python benchmarks/bench_diagnose.py --log ../shared/realdata/revs_250lm/revs_250lm_laps_0-400s.csv \
        --vehicle revs_250lm [--seconds 60]

With ``--log`` a real log (its first ``--seconds``, default all) is diagnosed instead, on its own
held-out segments, with every candidate: the issue's speed acceptance on time-varying speed (the race
car: under 300 s for the 400 s log). Prints the time of each step, the verdict and the fitted values.
"""

from __future__ import annotations

import argparse
import time

import _checkout  # noqa: F401 -- this checkout's online_id, not an installed copy

from online_id.diagnosis.diagnose import diagnose_gap
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
    ap.add_argument("--log", help="diagnose this real track-run CSV instead of the simulated matrix")
    ap.add_argument("--vehicle", default="haro2008", help="vehicle of --log (built-in name or TOML)")
    ap.add_argument("--seconds", type=float, help="use only the first SECONDS of --log")
    args = ap.parse_args()
    if args.log:
        real_log(args)
        return
    vehicle = load_vehicle("haro2008")
    truth = vehicle.truth("track")
    for case in args.case or CASES:
        effects = [] if case == "none" else [parse_effect(t) for t in case.split(",")]
        run = simulate(vehicle, truth, duration_s=args.duration, seed=1, effects=effects).run
        val = simulate(vehicle, truth, duration_s=args.duration, seed=2, speed_mps=60 / 3.6, effects=effects).run
        t0 = time.perf_counter()
        d = diagnose_gap(vehicle, run, val)
        wall = time.perf_counter() - t0
        best = d.candidates[0]
        sig = ", ".join(f"{c.fit.label} {100 * c.reduction:.1f}%" for c in d.candidates if c.significant) or "none"
        params = ", ".join(f"{k}={v:.4g}" for e in best.fit.effects for k, v in e.values.items())
        combo = f"; together: {d.combination['label']} {100 * d.combination['reduction']:.1f}%" \
            if d.combination else ""
        print(f"{case:<50} verdict {str(d.verdict):<22} best {best.fit.label} {100 * best.reduction:5.1f}%"
              f" ({params}); significant: {sig}{combo}; {wall:.1f} s", flush=True)


def real_log(args) -> None:
    from online_id.io.tracklog import read_track_run

    vehicle = load_vehicle(args.vehicle)
    run = read_track_run(args.log)
    if args.seconds:
        run = run.slice(0, int(round(args.seconds / (run.time[1] - run.time[0]))))
    t0 = time.perf_counter()
    last = [t0]

    def progress(what, i, n):
        now = time.perf_counter()
        print(f"  [{i}/{n}] {what} (after {now - t0:.1f} s)", flush=True)
        last[0] = now

    d = diagnose_gap(vehicle, run, progress=progress)
    wall = time.perf_counter() - t0
    print(f"{args.log} ({len(run)} samples, {run.time[-1] - run.time[0]:.0f} s): verdict {d.verdict};"
          f" held-out base cost {d.base_held_out_cost:.4g}; {wall:.1f} s")
    for c in d.candidates:
        params = ", ".join(f"{k}={v:.4g}" for e in c.fit.effects for k, v in e.values.items())
        print(f"  {c.fit.label:<40} reduction {100 * c.reduction:6.1f}%  ΔBIC {c.delta_bic:9.0f}"
              f"  {'significant' if c.significant else '-'}  {params}")
    print("  base model: " + ", ".join(f"{k}={v:.4g}" for k, v in zip(
        ("Mzz", "Mxx", "D1", "D2", "Aro", "Kro", "b1", "b2"), d.base.theta)))


if __name__ == "__main__":
    main()
