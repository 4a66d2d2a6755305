"""What `listen --web` costs the estimation loop: the 60 s built-in run through the EKF, with the live page's
view called after every sample as `listen` calls it, timing the loop and the time spent inside the view.

    python benchmarks/bench_live_page.py [--repeat 3]

Prints, per repeat, the loop's wall time, the time inside the view and its share, and µs per sample. The
view reads the filter every READ_PERIOD_S of wall time (each read makes the EKF bring its grouped steps
up to date) and judges it every VERDICT_PERIOD_S; between two reads it counts.
"""

from __future__ import annotations

import argparse
import time

import _checkout  # noqa: F401 -- this checkout's online_id, not an installed copy

from online_id.estimation import make_estimator
from online_id.report.live import READ_PERIOD_S, VERDICT_PERIOD_S, LiveView
from online_id.sim.simulator import simulate
from online_id.stream.samples import samples_from_run
from online_id.vehicle import load_vehicle


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    car = load_vehicle("haro2008")
    run = simulate(car, car.truth("track"), duration_s=60.0, rate_hz=1000.0, seed=0).run
    samples = list(samples_from_run(run))
    print(f"{len(samples)} samples; the view reads every {READ_PERIOD_S:g} s, judges every {VERDICT_PERIOD_S:g} s")
    for k in range(args.repeat):
        est, view = make_estimator(car, "ekf"), LiveView("bench")
        inside = 0.0
        t0 = time.perf_counter()
        for s in samples:
            est.update(s)
            a = time.perf_counter()
            view(est, s, None)
            inside += time.perf_counter() - a
        total = time.perf_counter() - t0
        print(f"repeat {k + 1}: loop {total:.2f} s, inside the view {inside:.3f} s ({100 * inside / total:.2f} %),"
              f" {1e6 * inside / len(samples):.2f} µs per sample")


if __name__ == "__main__":
    main()
