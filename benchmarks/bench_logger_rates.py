"""The polish at a logger's rate: the steering between samples held against the curve through them (issue 36).

Run: python benchmarks/bench_logger_rates.py [--seeds 5] [--rates 100,25] [--kinds hold,linear,cubic]
     [--start prior|near]

The built-in run (Haro's 0.2-4 Hz chirp, 22°, 80 km/h, 60 s, Table 6 car) integrated at 10 kHz (the cubic's exact
steps, :func:`online_id.sim.simulator.simulate` with ``integration_rate_hz``) and logged at each rate, sensor noise
added after sampling; the polish (:func:`online_id.batchfit.polish.polish`) from the vehicle's prior (``--start
prior``) or from the truth × 1.1 (``near``), with each intersample model. Prints per parameter the mean relative
error over the seeds [%] and its mean in the polish's own σ (z), then the polish's wall time (median) and
evaluations. A logger's car, not the filters' own discretisation: with the hold every run built at the
logged rate hid the half-sample lag this measures.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402

import _checkout  # noqa: E402, F401 -- this checkout's online_id, not an installed copy
import numpy as np  # noqa: E402

from online_id.batchfit.polish import POLISH_BURN_IN_S, polish  # noqa: E402
from online_id.filters.config import FilterConfig  # noqa: E402
from online_id.sim.simulator import FINE_RATE_HZ, simulate  # noqa: E402
from online_id.vehicle import PARAMETER_NAMES, load_vehicle  # noqa: E402

CAR = load_vehicle("haro2008")
TRUTH = CAR.truth("track")
NEAR = 1.1


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--rates", default="100,25", help="logged rates [Hz], comma-separated")
    ap.add_argument("--kinds", default="hold,linear,cubic", help="intersample models, comma-separated")
    ap.add_argument("--start", choices=("prior", "near"), default="prior")
    args = ap.parse_args()
    truth = TRUTH.to_vector()
    std = FilterConfig().measurement_std
    start = CAR.prior.to_vector() if args.start == "prior" else NEAR * truth
    print(f"built-in chirp integrated at {FINE_RATE_HZ:g} Hz, {args.seeds} noise seeds, polish from"
          f" {'the prior' if args.start == 'prior' else f'{NEAR:g} × the truth'}; mean error % (mean z)")
    for rate in (float(r) for r in args.rates.split(",")):
        runs = [simulate(CAR, TRUTH, rate_hz=rate, integration_rate_hz=FINE_RATE_HZ, seed=s).run
                for s in range(args.seeds)]
        print(f"\n{rate:g} Hz   " + "".join(f"{n:>17}" for n in PARAMETER_NAMES) + "   wall s  evals")
        for kind in args.kinds.split(","):
            err, z, wall, evals, failed = [], [], [], [], 0
            for run in runs:
                t0 = time.perf_counter()
                try:
                    p = polish(CAR, run, start, std, burn_in_s=POLISH_BURN_IN_S, intersample=kind)
                except Exception as exc:  # noqa: BLE001 - a benchmark reports and goes on
                    failed += 1
                    print(f"  {kind}: {exc}")
                    continue
                wall.append(time.perf_counter() - t0)
                evals.append(p.iterations)
                e = p.theta / truth - 1
                err.append(e)
                z.append(e / p.relative_std)
            if not err:
                continue
            e, zz = np.mean(err, axis=0), np.mean(z, axis=0)
            cells = "".join(f"{100 * a:>+9.2f} ({b:>+5.1f})" for a, b in zip(e, zz))
            print(f"{kind:<9}{cells}   {statistics.median(wall):6.2f}  {statistics.median(evals):5.0f}"
                  + (f"  ({failed} failed)" if failed else ""))


if __name__ == "__main__":
    main()
