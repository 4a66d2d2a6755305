"""The whole estimate against a bare filterpy loop (issue 26 item 2: the per-sample step compiled).

Run: python benchmarks/bench_fast.py [--repeat 3]

Prints, all timed in this one run (``--repeat`` times each, interleaved so that drift on a shared machine
hits all alike; the median is the figure, the minimum beside it), in wall time and, below, in CPU time (user +
system; what a busy machine disturbs less):

* the baseline: a bare filterpy ``KalmanFilter`` predict+update loop, 14 states, 4 outputs, over 60,000
  samples (benchmarks/bench_filters.py's ``bare_filterpy``), in seconds and µs per sample;
* ``online-id estimate`` on the built-in 60 s, 1 kHz run, whole command in a subprocess (wall time including
  start-up, the simulation of the run, the filter and the polish), EKF and ``--filter ukf``, as ratios to the
  baseline's 60,000 samples (targets: EKF ≤ 0.5x, UKF ≤ 2x);
* the filter alone on the same run (``run_estimator`` over its arrays, one core): µs per sample and the
  ratio to the bare step; and the same fed one sample at a time (the streaming ``update``), for comparison.

``--intersample hold,cubic`` times the filter alone with each input between samples
(:class:`~online_id.filters.FilterConfig` ``intersample``), interleaved in the same repeats (the whole
command runs with the command's own default).
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import resource  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import _checkout  # noqa: E402
from bench_filters import bare_filterpy  # noqa: E402

from online_id.estimation import make_estimator, run_estimator  # noqa: E402
from online_id.filters import FilterConfig  # noqa: E402
from online_id.sim.simulator import simulate  # noqa: E402
from online_id.stream.samples import SampleArrays, samples_from_run  # noqa: E402
from online_id.vehicle import load_vehicle  # noqa: E402

N = 60000  # samples of the built-in run (60 s at 1 kHz), and of the baseline
TARGETS = {"ekf": 0.5, "ukf": 2.0}


def whole_command(filt: str) -> tuple[float, float]:
    """(wall, CPU) time [s] of ``online-id estimate --filter FILT`` on the built-in run, in a fresh process."""
    env = dict(os.environ, PYTHONPATH=str(_checkout.ROOT))
    cmd = [sys.executable, "-m", "online_id.cli.main", "estimate", "--quiet", "--filter", filt]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env,
                   cwd=_checkout.ROOT)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def filter_only(car, filt: str, samples, intersample: str = "hold") -> tuple[float, float]:
    """(wall, CPU) µs per sample of the filter alone over ``samples`` (SampleArrays: the array path; a list: per
    sample), with the input between samples ``intersample``."""
    c0 = time.process_time()
    res = run_estimator(make_estimator(car, filt, config=FilterConfig(intersample=intersample)), samples)
    return res.wall_s / res.samples * 1e6, (time.process_time() - c0) / res.samples * 1e6


def bare(n: int) -> tuple[float, float]:
    """(wall, CPU) µs per sample of the bare filterpy loop."""
    c0 = time.process_time()
    wall = bare_filterpy(n)
    return wall, (time.process_time() - c0) / n * 1e6


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--intersample", default="hold",
                    help="comma-separated inputs between samples to time the filter alone with (default: hold)")
    args = ap.parse_args()
    kinds = args.intersample.split(",")
    car = load_vehicle("haro2008")
    run = simulate(car, car.truth("track"), seed=0).run  # the built-in run
    arrays, samples = SampleArrays.from_run(run), list(samples_from_run(run))
    assert len(arrays) == N
    short = SampleArrays.from_run(simulate(car, car.truth("track"), duration_s=0.5).run)
    for filt in TARGETS:  # compile or load the compiled loops before timing
        for kind in kinds:
            filter_only(car, filt, short, kind)
    base, whole = [], {f: [] for f in TARGETS}
    alone, streamed = ({(f, k): [] for f in TARGETS for k in kinds} for _ in range(2))
    for _ in range(max(1, args.repeat)):
        base.append(bare(N))
        for filt in TARGETS:
            whole[filt].append(whole_command(filt))
            for kind in kinds:
                alone[filt, kind].append(filter_only(car, filt, arrays, kind))
                streamed[filt, kind].append(filter_only(car, filt, samples, kind))
    for i, clock in enumerate(("wall", "CPU")):
        b = [x[i] for x in base]
        base_us = statistics.median(b)
        base_s = base_us * N / 1e6
        print(f"{clock} time. baseline: bare filterpy KalmanFilter predict+update, 14 states, 4 outputs, {N} samples:"
              f" {base_s:.2f} s = {base_us:.1f} µs/sample (median of {len(b)}, min {min(b):.1f})")
        print(f"{'':<4} {'whole command':>14} {'ratio':>7} {'target':>7}        {'filter µs/sample':>20} {'ratio':>6}"
              f"   {'per-sample update µs':>20} {'ratio':>6}")
        for filt, target in TARGETS.items():
            w_all = [x[i] for x in whole[filt]]
            w = statistics.median(w_all)
            verdict = "ok" if w / base_s <= target else "MISSED"
            for j, kind in enumerate(kinds):
                a_all, s_all = ([x[i] for x in d[filt, kind]] for d in (alone, streamed))
                a, s = statistics.median(a_all), statistics.median(s_all)
                head = (f"{filt:<4} {w:>12.2f} s {w / base_s:>6.2f}x {target:>6.1f}x {verdict:<6}" if j == 0
                        else f"{'':<4} {'':>14} {'':>7} {'':>7} {'':<6}")
                label = f" {kind:<5}" if len(kinds) > 1 else ""
                print(f"{head}{label} {a:>10.1f} (min {min(a_all):5.1f}) {a / base_us:>5.2f}x"
                      f"   {s:>10.1f} (min {min(s_all):5.1f}) {s / base_us:>5.2f}x")
    print(f"(whole command: `online-id estimate [--filter ukf]` incl. start-up, the built-in run's simulation and the"
          f" polish; filter: over the run's arrays, and fed one sample at a time; medians of {args.repeat})")


if __name__ == "__main__":
    main()
