"""The tyre fits' Jacobian columns on threads (issue 40, item 1): a diagnosis one thread against N, pair by pair.

    python benchmarks/bench_fit_threads.py [--log LOG] [--vehicle revs_250lm] [--split 300] [--threads 2]
        [--repeat 1] [--channels yaw_rate,lateral_acceleration]

The race log (default ``../shared/realdata/revs_250lm/revs_250lm_laps_0-400s.csv``) fitted before ``--split`` seconds
and judged after it, on ``--channels``, with ``tire_saturation`` and its refinement chain (a μ per axle, the loads
moved by a_x, combined slip): the fits whose Jacobians take one RK4 pass a column. Each pair runs
``ONLINE_ID_FIT_THREADS=1`` then ``--threads`` (the baseline is the serial run of the same code); prints both wall
times, their medians and ratio, and whether the two answers are the same (verdict, carry, every held-out cost).
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path

import _checkout  # noqa: F401 -- this checkout's online_id, not an installed copy

from online_id.diagnosis.diagnose import diagnose_gap
from online_id.diagnosis.fitting import THREADS_ENV
from online_id.io.tracklog import read_track_run
from online_id.vehicle.loader import load_vehicle
from online_id.workflows.inputs import only_run_channels

RACE = Path(__file__).resolve().parents[2] / "shared" / "realdata" / "revs_250lm" / "revs_250lm_laps_0-400s.csv"


def _cut(run, start: float, stop: float):
    from dataclasses import fields, replace

    keep = (run.time >= start) & (run.time < stop)
    arrays = {f.name: getattr(run, f.name)[keep] for f in fields(run)
              if hasattr(getattr(run, f.name), "shape") and getattr(run, f.name).shape == run.time.shape}
    return replace(run, **arrays)


def _once(vehicle, train, held, threads: int):
    os.environ[THREADS_ENV] = str(threads)
    t = time.perf_counter()
    d = diagnose_gap(vehicle, train, held, effects=["tire_saturation"])
    wall = time.perf_counter() - t
    answer = (d.verdict, d.carry, [c.held_out_cost for c in d.candidates],
              [(r.get("tried"), r["held_out_cost_after"]) for r in d.refinements])
    return wall, answer


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--log", default=str(RACE))
    ap.add_argument("--vehicle", default="revs_250lm")
    ap.add_argument("--split", type=float, default=300.0, help="fit before, judge after [s] (default 300)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=1, help="pairs (default 1)")
    ap.add_argument("--channels", default="yaw_rate,lateral_acceleration")
    args = ap.parse_args()
    vehicle = load_vehicle(args.vehicle)
    run = only_run_channels(read_track_run(args.log), args.channels)
    train, held = _cut(run, -float("inf"), args.split), _cut(run, args.split, float("inf"))
    serial, threaded, same = [], [], True
    for k in range(args.repeat):
        w1, a1 = _once(vehicle, train, held, 1)
        wn, an = _once(vehicle, train, held, args.threads)
        serial.append(w1)
        threaded.append(wn)
        same &= a1 == an
        print(f"pair {k + 1}: 1 thread {w1:.1f} s, {args.threads} threads {wn:.1f} s; verdict {a1[0]}, carry "
              f"{a1[1].get('online') if a1[1] else None}", flush=True)
    m1, mn = statistics.median(serial), statistics.median(threaded)
    print(f"\nmedian of {args.repeat}: 1 thread {m1:.1f} s, {args.threads} threads {mn:.1f} s, ratio {mn / m1:.2f}"
          f" (baseline: the same code one column at a time); answers {'the same' if same else 'DIFFER'}")


if __name__ == "__main__":
    main()
