"""Time to simulate Haro's 60 s, 1 kHz chirp run (Table 6 car, 80 km/h, sensor noise).

Run: python benchmarks/bench_simulate.py [--repeat N]
Prints the median and best wall time and the real-time factor (simulated seconds per wall second).
"""

from __future__ import annotations

import argparse
import statistics
import time

import _checkout  # noqa: F401 -- this checkout's online_id, not an installed copy

from online_id.sim.simulator import simulate
from online_id.vehicle import load_vehicle


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--repeat", type=int, default=7)
    args = ap.parse_args()
    car = load_vehicle("haro2008")
    th = car.truth("track")
    times = []
    for i in range(args.repeat):
        t0 = time.perf_counter()
        sim = simulate(car, th, duration_s=60.0, rate_hz=1000.0, seed=i)
        times.append(time.perf_counter() - t0)
    med = statistics.median(times)
    print(f"simulate 60 s at 1 kHz ({len(sim.run)} samples), {args.repeat} runs:")
    print(f"  median {med * 1e3:.1f} ms, best {min(times) * 1e3:.1f} ms,"
          f" {med / len(sim.run) * 1e6:.2f} µs/sample, real-time factor {60.0 / med:.0f}x")


if __name__ == "__main__":
    main()
