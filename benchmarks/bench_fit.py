"""Hybrid GA (Haro) against scipy's differential_evolution on the same cost and bounds.

Run: python benchmarks/bench_fit.py [--seed 0] [--de-maxiter 400]

Both minimise Haro's cost (eq 12 on 10-sample block means) over the built-in run (80 km/h chirp,
Table 6 car, noise) in log-scale space within 0.2×-5× the constructor prior, without the local
polish. Printed per method: evaluations and wall time to first reach a cost within 1 % of the best
cost either method found, the final cost, and each parameter's error against truth.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import time  # noqa: E402

import _checkout  # noqa: E402, F401 -- this checkout's online_id, not an installed copy
import numpy as np  # noqa: E402
from scipy.optimize import differential_evolution  # noqa: E402

from online_id.batchfit.cost import FitCost  # noqa: E402
from online_id.batchfit.ga import GAConfig, hybrid_ga  # noqa: E402
from online_id.sim.simulator import simulate  # noqa: E402
from online_id.vehicle import PARAMETER_NAMES, load_vehicle  # noqa: E402


class Recorder:
    """Wraps the cost: best-so-far after every evaluation, with its wall time."""

    def __init__(self, cost: FitCost):
        self.cost = cost
        self.best = np.inf
        self.best_x = None
        self.trace: list[tuple[int, float, float]] = []  # (evaluations, seconds, best)
        self.t0 = time.perf_counter()

    def one(self, s) -> float:
        c = self.cost(s)
        if c < self.best:
            self.best, self.best_x = c, np.array(s, dtype=float)
        self.trace.append((len(self.trace) + 1, time.perf_counter() - self.t0, self.best))
        return c

    def batch(self, S) -> np.ndarray:
        return np.array([self.one(s) for s in np.atleast_2d(S)])

    def reach(self, target: float) -> tuple[int, float] | None:
        for n, t, b in self.trace:
            if b <= target:
                return n, t
        return None


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--de-maxiter", type=int, default=400, help="DE generations (15×8 = 120 evaluations each)")
    args = ap.parse_args()
    car = load_vehicle("haro2008")
    truth = car.truth("track")
    run = simulate(car, truth, seed=1).run
    theta0 = car.prior.to_vector()
    lower, upper = np.full(8, np.log(0.2)), np.full(8, np.log(5.0))

    ga = Recorder(FitCost(car, run, theta0))
    hybrid_ga(ga.batch, lower, upper, GAConfig(), seed=args.seed, initial=np.zeros((1, 8)))
    de = Recorder(FitCost(car, run, theta0))
    differential_evolution(de.one, list(zip(lower, upper)), seed=args.seed, maxiter=args.de_maxiter, polish=False,
                           x0=np.zeros(8), tol=1e-8)
    best = min(ga.best, de.best)
    target = best * 1.01
    truth_cost = ga.cost(np.log(truth.to_vector() / theta0))
    print(f"cost at the true parameters: {truth_cost:.6g}; best found: {best:.6g}; target (best + 1 %): {target:.6g}")
    print(f"{'method':<24} {'evals→target':>13} {'s→target':>9} {'total evals':>12} {'total s':>8} {'final cost':>11}"
          "  max |error|")
    reached = {}
    for name, rec in (("hybrid GA (Haro)", ga), ("differential_evolution", de)):
        r = rec.reach(target)
        reached[name] = r
        err = theta0 * np.exp(rec.best_x) / truth.to_vector() - 1
        ev, secs = (f"{r[0]}", f"{r[1]:.1f}") if r else ("not reached", "-")
        print(f"{name:<24} {ev:>13} {secs:>9} {len(rec.trace):>12} {rec.trace[-1][1]:>8.1f} {rec.best:>11.6g}"
              f"  {100 * np.abs(err).max():.3f}%")
        print("    error %: " + "  ".join(f"{p} {100 * e:+.3f}" for p, e in zip(PARAMETER_NAMES, err)))
    g, d = reached["hybrid GA (Haro)"], reached["differential_evolution"]
    if g and d:
        print(f"ratio DE/GA to reach the target: evaluations {d[0] / g[0]:.2f}x, wall time {d[1] / g[1]:.2f}x")


if __name__ == "__main__":
    main()
