"""``online-id batch`` over 8 logs: wall time with 2 Dask workers against 1, in one run.

Run: python benchmarks/bench_batch.py [--logs 8] [--duration 60] [--repeat 1]
Simulates the logs once (Haro's chirp, 1 kHz, different seeds and speeds), then times
``run_batch`` (local cluster start-up and shut-down included, every log forced to run) with
1 and with 2 workers, alternating, and prints each time and the ratio 2 workers / 1 worker
(issue 16 asks for at most 0.6). Pass ``--workers-only 0`` to add the inline run (no Dask).
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import _checkout  # noqa: F401 -- this checkout's online_id, not an installed copy

from online_id.batch import BatchOptions, run_batch
from online_id.io.tracklog import write_track_run
from online_id.sim.simulator import simulate
from online_id.vehicle import load_vehicle


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--logs", type=int, default=8)
    ap.add_argument("--duration", type=float, default=60.0, help="seconds per log (default 60, the built-in run)")
    ap.add_argument("--repeat", type=int, default=1, help="alternating runs per worker count (default 1)")
    args = ap.parse_args()
    car = load_vehicle("haro2008")
    with tempfile.TemporaryDirectory() as d:
        logs = []
        for i in range(args.logs):
            sim = simulate(car, car.truth("track"), duration_s=args.duration, seed=i, speed_mps=(70 + 3 * i) / 3.6)
            p = Path(d) / f"run{i}.csv"
            write_track_run(sim.run, p)
            logs.append(p)
        times: dict[int, list[float]] = {1: [], 2: []}
        for _ in range(args.repeat):
            for w in (1, 2):
                t0 = time.perf_counter()
                res = run_batch(logs, Path(d) / f"out{w}", BatchOptions(), workers=w, force=True)
                times[w].append(time.perf_counter() - t0)
                assert not res.failed, res.failed
        print(f"batch of {args.logs} logs ({args.duration:g} s at 1 kHz each), EKF, local Dask cluster:")
        for w, ts in times.items():
            print(f"  {w} worker(s): median {statistics.median(ts):.2f} s, best {min(ts):.2f} s ({len(ts)} runs)")
        ratio = statistics.median(times[2]) / statistics.median(times[1])
        print(f"  ratio 2 workers / 1 worker: {ratio:.2f} (issue 16: at most 0.6)")


if __name__ == "__main__":
    main()
