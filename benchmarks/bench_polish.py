"""The efficient final estimate: EKF + batch polish on Haro's 60 s, 1 kHz chirp at 80 km/h, over noise seeds.

Run: python benchmarks/bench_polish.py [--seeds 20] [--workers 2] [--intersample hold|linear|cubic]
     [--integration-rate HZ]

Prints, per parameter, the RMSE of the relative error over the seeds of the filter alone and of the
filter followed by the polish (:mod:`online_id.batchfit.polish`), each against the Cramér-Rao bound of the
run (RMSE/CRLB; acceptance: ≤ 2 for every parameter with the polish), the mean reported σ of the
polish against the RMSE (an honest covariance gives about 1), and the real-time factor of filter +
polish (60 s of data per wall second, per seed, one core each; the machine may be shared, so it is
also given as the polish's share of the time). ``--intersample``: the steering between samples the polish takes
(:mod:`online_id.model.intersample`); ``--integration-rate``: the rate the car is integrated at (default the
simulator's; a run integrated at its 1 kHz log rate holds the steering, and only the hold describes it).
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")  # one core per seed
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import time  # noqa: E402
from concurrent.futures import ProcessPoolExecutor  # noqa: E402
from functools import partial  # noqa: E402

import _checkout  # noqa: E402, F401 -- this checkout's online_id, not an installed copy
import numpy as np  # noqa: E402

from online_id.batchfit.polish import POLISH_BURN_IN_S, polish_estimate  # noqa: E402
from online_id.estimation import make_estimator, run_estimator  # noqa: E402
from online_id.filters import FilterConfig  # noqa: E402
from online_id.sim.simulator import INTEGRATION_RATE_HZ, SensorNoise, simulate  # noqa: E402
from online_id.stream.samples import samples_from_run  # noqa: E402
from online_id.trust.identifiability import fisher_information  # noqa: E402
from online_id.vehicle import PARAMETER_NAMES, load_vehicle  # noqa: E402

CAR = load_vehicle("haro2008")
TRUTH = CAR.truth("track")
DURATION_S = 60.0


def run_seed(seed: int, intersample: str = "hold", integration_rate_hz: float | None = INTEGRATION_RATE_HZ):
    run = simulate(CAR, TRUTH, seed=seed, integration_rate_hz=integration_rate_hz).run
    t0 = time.perf_counter()
    result = run_estimator(make_estimator(CAR, "ekf"), samples_from_run(run))
    t1 = time.perf_counter()
    online = result.parameters.to_vector() / TRUTH.to_vector() - 1
    config = FilterConfig()
    problem = polish_estimate(result, CAR, run, config.measurement_std, burn_in_s=POLISH_BURN_IN_S,
                              prior_log_std_floor=config.prior_log_std_floor, intersample=intersample)
    t2 = time.perf_counter()
    polished = result.parameters.to_vector() / TRUTH.to_vector() - 1
    return online, polished, result.relative_std, t1 - t0, t2 - t1, problem


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--workers", type=int, default=os.cpu_count())
    ap.add_argument("--intersample", choices=("hold", "linear", "cubic"), default="hold")
    ap.add_argument("--integration-rate", type=float, default=INTEGRATION_RATE_HZ)
    args = ap.parse_args()
    noise = SensorNoise()
    fisher = fisher_information(CAR, TRUTH, simulate(CAR, TRUTH, seed=0).run,
                                {"yaw_rate": noise.yaw_rate, "roll_angle": noise.roll_angle,
                                 "roll_rate": noise.roll_rate, "lateral_acceleration": noise.lateral_acceleration})
    crlb = fisher.crlb_relative_std
    with ProcessPoolExecutor(max_workers=args.workers) as pool:
        results = list(pool.map(partial(run_seed, intersample=args.intersample,
                                        integration_rate_hz=args.integration_rate), range(args.seeds)))
    online = np.array([r[0] for r in results])
    polished = np.array([r[1] for r in results])
    sd = np.array([r[2] for r in results])
    t_filter = np.array([r[3] for r in results])
    t_polish = np.array([r[4] for r in results])
    problems = [r[5] for r in results if r[5]]
    rmse_on, rmse_po = np.sqrt((online ** 2).mean(axis=0)), np.sqrt((polished ** 2).mean(axis=0))
    print(f"{args.seeds} seeds, EKF then polish (intersample {args.intersample}; the car integrated at"
          f" {args.integration_rate or 1000:g} Hz); Cramér-Rao bound from the run's Fisher information")
    print(f"{'param':<5} {'CRLB %':>8} {'EKF RMSE %':>11} {'EKF/CRLB':>9} {'polish RMSE %':>14} {'polish/CRLB':>12}"
          f" {'mean σ %':>9} {'RMSE/σ':>7}")
    for i, p in enumerate(PARAMETER_NAMES):
        print(f"{p:<5} {100 * crlb[i]:>8.4f} {100 * rmse_on[i]:>11.4f} {rmse_on[i] / crlb[i]:>9.2f}"
              f" {100 * rmse_po[i]:>14.4f} {rmse_po[i] / crlb[i]:>12.2f} {100 * sd[:, i].mean():>9.4f}"
              f" {rmse_po[i] / sd[:, i].mean():>7.2f}")
    worst = float(np.max(rmse_po / crlb))
    print(f"worst polish RMSE/CRLB {worst:.2f} ({'meets' if worst <= 2 else 'MISSES'} ≤ 2)")
    total = t_filter + t_polish
    print(f"wall per seed: filter {np.median(t_filter):.2f} s, polish {np.median(t_polish):.2f} s (median);"
          f" filter + polish {DURATION_S / np.median(total):.1f}x real time (slowest seed"
          f" {DURATION_S / total.max():.1f}x); polish share {np.median(t_polish / total):.0%}")
    if problems:
        print(f"polish fell back to the filter on {len(problems)} seeds: {problems[0]}")


if __name__ == "__main__":
    main()
