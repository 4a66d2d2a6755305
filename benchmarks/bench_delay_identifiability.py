"""Which delays the data can tell from the dynamics: the Cramér-Rao bound of the 8 and a delay together.

For each delay candidate (``sensor_delay`` on each channel, ``steering_delay``) on the built-in run (Haro's
0.2-4 Hz chirp, 80 km/h, Table 6 car, the simulator's sensor noise), prints the bound on τ, the correlation of
τ with each of the 8, and how much estimating τ widens each of the 8's bound (1.0: the run separates them).
Quoted in docs/guide/gap-diagnosis.md ("Which delays the data separate").

    .venv/bin/python benchmarks/bench_delay_identifiability.py [--duration 60] [--rate 1000] [--delay 0.025]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from online_id.effects import EFFECTS
from online_id.sim.simulator import SensorNoise, simulate
from online_id.trust.identifiability import effect_information
from online_id.vehicle.loader import load_vehicle
from online_id.vehicle.parameters import PARAMETER_NAMES


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--rate", type=float, default=1000.0)
    ap.add_argument("--delay", type=float, default=0.025, help="the delay at which the bound is taken [s]")
    ap.add_argument("--speed-kmh", type=float, default=80.0)
    args = ap.parse_args()
    car = load_vehicle("haro2008")
    theta = car.truth("track")
    run = simulate(car, theta, duration_s=args.duration, rate_hz=args.rate, speed_mps=args.speed_kmh / 3.6,
                   noise=SensorNoise.none()).run
    noise = SensorNoise()
    noise_std = {"yaw_rate": noise.yaw_rate, "roll_angle": noise.roll_angle, "roll_rate": noise.roll_rate,
                 "lateral_acceleration": noise.lateral_acceleration}
    candidates = [EFFECTS["sensor_delay"](channel=c, delay_s=args.delay) for c in noise_std]
    candidates.append(EFFECTS["steering_delay"](delay_s=args.delay))
    print(f"built-in run: {args.duration:g} s at {args.rate:g} Hz, {args.speed_kmh:g} km/h;"
          f" delay {1e3 * args.delay:g} ms")
    print(f"{'candidate':<34} {'σ_τ [ms]':>9}  corr(τ, ·) / widening of the 8's bound")
    for e in candidates:
        t0 = time.perf_counter()
        info = effect_information(car, theta, run, noise_std, e)
        corr = info.correlation_with_effect()
        widen = info.inflation()
        worst = max(PARAMETER_NAMES, key=lambda n: abs(corr[n]))
        row = "  ".join(f"{n} {corr[n]:+.2f}/{widen[n]:.2f}x" for n in PARAMETER_NAMES)
        print(f"{e.label:<34} {1e3 * info.crlb[-1]:>9.4f}  {row}  (most: {worst}; {time.perf_counter() - t0:.1f} s)")
        print(f"{'':<34} {'':>9}  bound on the 8 with τ free [%]: "
              + " ".join(f"{n} {100 * s:.3f}" for n, s in zip(PARAMETER_NAMES, info.crlb[:8])))


if __name__ == "__main__":
    np.set_printoptions(precision=3)
    main()
