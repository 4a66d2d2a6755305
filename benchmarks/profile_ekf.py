"""Where the EKF's time goes, per sample, on the built-in 60 s, 1 kHz run (one core).

    python benchmarks/profile_ekf.py [--filter ekf|ukf] [--duration 60] [--rate HZ]

``--rate HZ``: the run logged at that rate (a logger's 100 Hz: integrated at 10 kHz, as ``simulate``) and fed
as arrays (``update_many``, the path ``estimate`` takes), with each hook's time also per correction.

Wraps the estimator's hooks with wall-clock timers (cheaper and less distorting than cProfile at
these call counts) and prints each hook's total and its share per sample. Nested hooks are
included in their callers' figures (``correct``, the health's, contains ``_flush``, ``_apply_correction``, ...).
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import functools  # noqa: E402
import time  # noqa: E402

import _checkout  # noqa: E402, F401 -- this checkout's online_id, not an installed copy

from online_id.estimation import make_estimator  # noqa: E402
from online_id.filters import FILTERS  # noqa: E402
from online_id.sim.simulator import simulate  # noqa: E402
from online_id.stream.samples import SampleArrays, samples_from_run  # noqa: E402
from online_id.vehicle import load_vehicle  # noqa: E402

HOOKS = ("_plain_run", "_close_block", "_tables", "_propagate_observe_many", "_propagate", "_observe", "_catch_up",
         "_recursed", "_absorb", "_linearise", "_measurement_vector", "_flush", "_block_innovation",
         "_apply_correction")
#: The shared guards' steps (``estimator.health``, online_id/filters/health.py).
HEALTH_HOOKS = ("correct", "check", "adapt_r", "listening")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--filter", choices=tuple(FILTERS), default="ekf")
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--rate", type=float, help="log the run at this rate [Hz] and feed it as arrays")
    args = ap.parse_args()
    car = load_vehicle("haro2008")
    if args.rate:
        run = simulate(car, car.truth("track"), duration_s=args.duration, rate_hz=args.rate, seed=0).run
        samples = SampleArrays.from_run(run)
    else:
        samples = list(samples_from_run(simulate(car, car.truth("track"), duration_s=args.duration, seed=0).run))
    est = make_estimator(car, args.filter)
    spent: dict[str, float] = {}
    for obj, name in [(est, n) for n in HOOKS] + [(est.health, n) for n in HEALTH_HOOKS]:
        if not hasattr(obj, name):
            continue
        original = getattr(obj, name)

        def timed(*a, _f=original, _n=name, **k):
            t = time.perf_counter()
            try:
                return _f(*a, **k)
            finally:
                spent[_n] = spent.get(_n, 0.0) + time.perf_counter() - t

        setattr(obj, name, functools.wraps(original)(timed))
    t0 = time.perf_counter()
    if args.rate:
        est.update_many(samples)
    else:
        for s in samples:
            est.update(s)
    total = time.perf_counter() - t0
    n = len(samples)
    corrections = max(est.events["corrections"], 1)
    print(f"{args.filter}: {n} samples in {total:.2f} s = {total / n * 1e6:.1f} µs/sample,"
          f" {args.duration / total:.1f}x real time (timers included), {corrections} corrections")
    for name, s in sorted(spent.items(), key=lambda kv: -kv[1]):
        print(f"  {name:<24} {s:6.2f} s  {s / n * 1e6:6.1f} µs/sample  {s / corrections * 1e6:7.1f} µs/correction")


if __name__ == "__main__":
    main()
