"""Time to simulate Haro's 60 s, 1 kHz chirp run (Table 6 car, 80 km/h, sensor noise), at the log's rate and
integrated finer than it is logged (issue 36: ``simulate(..., integration_rate_hz=...)``).

Run: python benchmarks/bench_simulate.py [--repeat N] [--integration-rate HZ]

Prints the median and best wall time and the real-time factor (simulated seconds per wall second) of: the
built-in run logged at 1 kHz, at the log's rate with the steering held (what ``online-id estimate`` without a
LOG simulates today) and integrated at ``--integration-rate`` (default 10 kHz); the same logged at 100 Hz; and a
tyre run with an effect (20 s of a 60° chirp, ``tire_saturation=0.7``, 0.8 g, logged at 100 Hz).
"""

from __future__ import annotations

import argparse
import statistics
import time

import _checkout  # noqa: F401 -- this checkout's online_id, not an installed copy
import numpy as np

from online_id.effects import parse_effect
from online_id.sim.simulator import FINE_RATE_HZ, simulate
from online_id.vehicle import load_vehicle


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--integration-rate", type=float, default=FINE_RATE_HZ)
    args = ap.parse_args()
    car = load_vehicle("haro2008")
    th = car.truth("track")
    fine = args.integration_rate
    tyre = {"duration_s": 20.0, "amplitude_rad": np.deg2rad(60.0), "effects": [parse_effect("tire_saturation=0.7")]}
    cases = [("60 s logged at 1 kHz, at the log's rate (hold)", {"integration_rate_hz": None}),
             (f"60 s logged at 1 kHz, integrated at {fine:g} Hz", {"integration_rate_hz": fine}),
             ("60 s logged at 100 Hz, at the log's rate (hold)", {"rate_hz": 100.0, "integration_rate_hz": None}),
             (f"60 s logged at 100 Hz, integrated at {fine:g} Hz", {"rate_hz": 100.0, "integration_rate_hz": fine}),
             ("20 s tyre run (0.8 g) at 100 Hz, at the log's rate", {"rate_hz": 100.0, "integration_rate_hz": None,
                                                                     **tyre}),
             (f"20 s tyre run (0.8 g) at 100 Hz, integrated at {fine:g} Hz",
              {"rate_hz": 100.0, "integration_rate_hz": fine, **tyre})]
    simulate(car, th, duration_s=1.0, rate_hz=100.0, integration_rate_hz=fine)  # numba's cache, loaded once
    for label, options in cases:
        times = []
        for i in range(args.repeat):
            t0 = time.perf_counter()
            sim = simulate(car, th, seed=i, **options)
            times.append(time.perf_counter() - t0)
        med = statistics.median(times)
        duration = options.get("duration_s", 60.0)
        print(f"{label} ({len(sim.run)} samples), {args.repeat} runs: median {med * 1e3:.1f} ms, best"
              f" {min(times) * 1e3:.1f} ms, real-time factor {duration / med:.0f}x")


if __name__ == "__main__":
    main()
