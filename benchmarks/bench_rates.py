"""The online filters at a logger's rate (issue 36): accuracy, verdicts and the cost of a second of log.

Run: python benchmarks/bench_rates.py [--rates 25,50,100,200,1000] [--seeds 20] [--filters ekf,ukf]
     [--baseline DIR] [--repeat 5]

Accuracy: the built-in run (Haro's 0.2-4 Hz chirp, 22°, 80 km/h, 60 s, Table 6 car) integrated at 10 kHz and
logged at each rate (sensor noise added after sampling), one filter run per seed: the worst parameter's error
[%] and |z| (mean and worst over the seeds), and the share of runs the true model is judged INCONSISTENT (the
false alarms; the issue's bound 5 %).

Cost (``--baseline DIR``, a checkout with its own ``.venv``, e.g. the main before issue 36): seed 0's 100 Hz log
written as a CSV, then ``online-id estimate LOG --quiet --json`` by this checkout and by the baseline, pair by
pair (``--repeat``), the filter's own wall time (JSON ``wall_s_filter``) per second of log: medians and the
ratio (the issue's bound: no worse than the baseline's).
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import _checkout  # noqa: E402, F401 -- this checkout's online_id, not an installed copy
import numpy as np  # noqa: E402

from online_id.estimation import make_estimator, run_estimator  # noqa: E402
from online_id.io.tracklog import write_track_run  # noqa: E402
from online_id.sim.simulator import simulate  # noqa: E402
from online_id.stream.samples import samples_from_run  # noqa: E402
from online_id.vehicle import load_vehicle  # noqa: E402

CAR = load_vehicle("haro2008")
TRUTH = CAR.truth("track")
HERE = Path(__file__).resolve().parents[1]


def accuracy(rate: float, filter_name: str, seeds: int) -> dict:
    worst_err, worst_z, flagged, walls = [], [], 0, []
    for seed in range(seeds):
        run = simulate(CAR, TRUTH, rate_hz=rate, seed=100 + seed, truth_name="track").run
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = run_estimator(make_estimator(CAR, filter_name), samples_from_run(run))
        v = res.parameters.to_vector()
        worst_err.append(100 * np.abs(v / TRUTH.to_vector() - 1).max())
        worst_z.append(np.abs((v - TRUTH.to_vector()) / res.std).max())
        flagged += res.consistency["consistent"] is False
        walls.append(res.wall_s / 60.0)
    return {"err": worst_err, "z": worst_z, "flagged": flagged, "wall": walls}


def cost(checkout: Path, log: Path, out: Path) -> float:
    """The filter's wall time [s] per second of log from one ``estimate`` by ``checkout``'s venv."""
    exe = checkout / ".venv" / "bin" / "online-id"
    subprocess.run([str(exe), "estimate", str(log), "--quiet", "--json", str(out)], check=True,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    data = json.loads(out.read_text())
    return data["wall_s_filter"] / 60.0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rates", default="25,50,100,200,1000", help="logged rates [Hz] (default: 25,50,100,200,1000)")
    ap.add_argument("--seeds", type=int, default=20, help="runs per rate and filter (default: 20)")
    ap.add_argument("--filters", default="ekf,ukf", help="filters (default: ekf,ukf)")
    ap.add_argument("--baseline", type=Path, metavar="DIR", help="a checkout with .venv to compare the cost with")
    ap.add_argument("--repeat", type=int, default=5, help="pairs of cost runs (default: 5)")
    args = ap.parse_args()
    rates = [float(r) for r in args.rates.split(",") if r]
    if args.seeds > 0:
        print(f"{'rate':>6} {'filter':>6} {'worst err % (mean, max)':>24} {'|z| (mean, max)':>16} "
              f"{'false alarms':>13} {'filter s / s of log':>20}", flush=True)
        for rate in rates:
            for f in args.filters.split(","):
                r = accuracy(rate, f, args.seeds)
                print(f"{rate:6.0f} {f:>6} {np.mean(r['err']):11.2f} {np.max(r['err']):11.2f} "
                      f"{np.mean(r['z']):7.2f} {np.max(r['z']):7.2f} "
                      f"{r['flagged']:4d}/{args.seeds:<3d} ({100 * r['flagged'] / args.seeds:3.0f} %) "
                      f"{statistics.median(r['wall']):10.4f}", flush=True)
    if args.baseline is None:
        return
    with tempfile.TemporaryDirectory() as tmp:
        log, out = Path(tmp) / "run100.csv", Path(tmp) / "out.json"
        write_track_run(simulate(CAR, TRUTH, rate_hz=100.0, seed=0, truth_name="track").run, log)
        mine, base = [], []
        for _ in range(args.repeat):  # pair by pair: the machine's drift hits both alike
            mine.append(cost(HERE, log, out))
            base.append(cost(args.baseline, log, out))
        m, b = statistics.median(mine), statistics.median(base)
        print(f"\n100 Hz, EKF, filter wall time per second of log (median of {args.repeat} pairs): this checkout "
              f"{1e3 * m:.2f} ms, baseline {args.baseline} {1e3 * b:.2f} ms, ratio {m / b:.2f}")
    sys.exit(0)


if __name__ == "__main__":
    main()
