"""The cost of the whole envelope: the filters with saturating tyres against the linear filters.

Run: python benchmarks/bench_tyres.py [--repeats 3]

The built-in protocol's 60 s at 1 kHz (80 km/h, a 60° chirp, tanh tyres of μ 0.8: 0.9 g), each filter over
the whole run, best of ``--repeats``; printed in µs per sample and as the ratio to the same filter without
the tyre model (issue 24's baseline: "at most 3x the linear EKF"). The linear filters run the same data
(their 0.5 g gate leaves out the samples beyond it, so they do less work per run, not per sample). Then the
polish with tyres (the filters' RK4 model with exact sensitivities) against the linear polish.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import time  # noqa: E402

import _checkout  # noqa: E402, F401 -- this checkout's online_id, not an installed copy
import numpy as np  # noqa: E402

from online_id.batchfit.polish import POLISH_BURN_IN_S, polish  # noqa: E402
from online_id.effects import parse_effect, parse_effect_to_estimate  # noqa: E402
from online_id.estimation import make_estimator, run_estimator  # noqa: E402
from online_id.filters.config import FilterConfig  # noqa: E402
from online_id.sim.simulator import simulate  # noqa: E402
from online_id.stream.samples import samples_from_run  # noqa: E402
from online_id.vehicle import load_vehicle  # noqa: E402

TARGET_RATIO = 3.0


def best_of(repeats: int, fn) -> tuple[float, object]:
    best, out = np.inf, None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    car = load_vehicle("haro2008")
    run = simulate(car, car.truth("track"), amplitude_rad=np.deg2rad(60),
                   effects=[parse_effect("tire_saturation=0.8")], seed=3).run
    samples = list(samples_from_run(run))
    n = len(samples)
    print(f"run: {n} samples at 1 kHz, peak |a_y| {np.max(np.abs(run.lateral_acceleration)) / 9.81:.2f} g")
    tyre = [parse_effect_to_estimate("tire_saturation")]
    for name in ("ekf", "ukf"):
        make_estimator(car, name, effects=tyre)  # compile (numba's cache) outside the timing
        lin_s, lin = best_of(args.repeats, lambda f=name: run_estimator(make_estimator(car, f), iter(samples)))
        tyr_s, tyr = best_of(args.repeats, lambda f=name: run_estimator(make_estimator(car, f, effects=tyre),
                                                                        iter(samples)))
        mu = tyr.extra_states["effects"]["tire_saturation"]["mu"]
        print(f"{name}: linear {1e6 * lin_s / n:.1f} µs/sample, with tyres {1e6 * tyr_s / n:.1f} µs/sample:"
              f" ratio {tyr_s / lin_s:.2f} (target ≤ {TARGET_RATIO:g}); μ {mu['value']:.4f} ± {mu['std']:.4f}")
    std = FilterConfig().measurement_std
    start = car.truth("track").to_vector() * 1.05
    lin_s, _ = best_of(args.repeats, lambda: polish(car, run, start, std, burn_in_s=POLISH_BURN_IN_S))
    tyr_s, p = best_of(args.repeats, lambda: polish(car, run, start, std, burn_in_s=POLISH_BURN_IN_S,
                                                    effects=[parse_effect_to_estimate("tire_saturation:1.0")]))
    print(f"polish from 5 % off: linear {lin_s:.2f} s, with tyres {tyr_s:.2f} s ({p.iterations} evaluations):"
          f" ratio {tyr_s / lin_s:.1f}; μ {p.effects['tire_saturation']['mu']['value']:.4f}")


if __name__ == "__main__":
    main()
