"""False-alarm rate and power of the consistency verdict (online_id/trust/consistency.py).

Run: python benchmarks/bench_consistency.py [--seeds 20] [--filters ekf,ukf] [--jobs 2] [--no-cases]

Prints, per filter:
  * the false-alarm rate: the fraction of clean built-in runs (Haro's 60 s chirp at 80 km/h, Table 6
    car, one noise seed each) judged inconsistent, with the reasons of each alarm; the issue's budget
    is 5 %;
  * the worst error against truth over those seeds (the clean runs must stay accurate);
  * the clean no-roll-channel run and a 60 km/h run (consistent expected);
  * the issue's slips (unless --no-cases): an a_y offset of 0.3 m/s², a yaw-rate offset of 0.02 rad/s,
    speed in km/h, SAE yaw sign, a_y in g, steering in degrees at a small amplitude, a car whose tyres
    saturate (μ 0.8): each must be flagged, and the first reason is shown.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import warnings  # noqa: E402
from concurrent.futures import ProcessPoolExecutor  # noqa: E402

import _checkout  # noqa: E402, F401 -- this checkout's online_id, not an installed copy
import numpy as np  # noqa: E402

from online_id.effects import parse_effect  # noqa: E402
from online_id.estimation import make_estimator, run_estimator  # noqa: E402
from online_id.sim.simulator import simulate  # noqa: E402
from online_id.stream.samples import samples_from_run  # noqa: E402
from online_id.trust.consistency import judge_estimator  # noqa: E402
from online_id.vehicle import load_vehicle  # noqa: E402

CAR = load_vehicle("haro2008")
TRUTH = CAR.truth("track")
from online_id.units import G  # noqa: E402

#: name -> (simulate keyword arguments, transformation of the logged run, channels)
CASES = {
    "clean": ({}, None, None),
    "clean, no roll channels": ({}, None, ("yaw_rate", "lateral_acceleration")),
    "clean, 60 km/h": ({"speed_mps": 60 / 3.6}, None, None),
    "a_y offset 0.3 m/s²": ({"effects": [parse_effect("sensor_bias=lateral_acceleration:0.3")]}, None, None),
    "yaw-rate offset 0.02 rad/s": ({"effects": [parse_effect("sensor_bias=yaw_rate:0.02")]}, None, None),
    "tyres saturating, μ 0.8": ({"effects": [parse_effect("tire_saturation=0.8")]}, None, None),
    "speed in km/h": ({}, lambda r: setattr(r, "speed", r.speed * 3.6), None),
    "SAE yaw sign": ({}, lambda r: setattr(r, "yaw_rate", -r.yaw_rate), None),
    "a_y in g": ({}, lambda r: setattr(r, "lateral_acceleration", r.lateral_acceleration / G), None),
    "steering in degrees, 3° amplitude": ({"amplitude_rad": np.deg2rad(3.0)},
                                           lambda r: setattr(r, "steering_wheel_angle",
                                                             np.rad2deg(r.steering_wheel_angle)), None),
}


def run_case(name: str, filt: str, seed: int):
    kwargs, transform, channels = CASES[name]
    run = simulate(CAR, TRUTH, seed=seed, **kwargs).run
    if transform is not None:
        transform(run)
    est = make_estimator(CAR, filt)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        res = run_estimator(est, samples_from_run(run, channels))
    err = np.abs(res.parameters.to_vector() / TRUTH.to_vector() - 1)
    informed = np.array(list(res.informed.values()))
    worst = float(err[informed].max()) if informed.any() else float("nan")
    return name, filt, seed, judge_estimator(est), worst


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--filters", default="ekf,ukf")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--no-cases", action="store_true")
    args = ap.parse_args()
    filters = args.filters.split(",")
    jobs = [("clean", f, s) for f in filters for s in range(args.seeds)]
    if not args.no_cases:
        jobs += [(c, f, 0) for c in CASES if c != "clean" for f in filters]
    with ProcessPoolExecutor(args.jobs) as pool:
        results = list(pool.map(run_case, *zip(*jobs)))
    for f in filters:
        clean = [r for r in results if r[0] == "clean" and r[1] == f]
        alarms = [r for r in clean if r[3]["consistent"] is False]
        print(f"{f.upper()}: false alarms on clean runs {len(alarms)}/{len(clean)}"
              f" = {100 * len(alarms) / len(clean):.0f} % (budget 5 %); worst error of an informed parameter"
              f" over the seeds {100 * max(r[4] for r in clean):.3f} %")
        for r in alarms:
            print(f"    seed {r[2]}: {'; '.join(r[3]['reasons'])}")
        rms = np.array([[d["rms_ratio"] for d in r[3]["innovations"]["channels"].values()] for r in clean])
        q = np.array([[d["sum_rho2"] for d in r[3]["innovations"]["channels"].values()] for r in clean])
        print(f"    clean runs: innovation RMS / expected {rms.min():.2f}-{rms.max():.2f};"
              f" Σρ² over {q.shape[1]} channels {q.min():.3f}-{q.max():.3f}")
        for r in results:
            if r[0] != "clean" and r[1] == f:
                c = r[3]
                verdict = {True: "consistent", None: "not judged"}.get(c["consistent"],
                                                                       f"FLAGGED ({len(c['reasons'])} reasons)")
                first = f": {c['reasons'][0]}" if c["consistent"] is False else ""
                print(f"  {r[0]:<36} worst informed error {100 * r[4]:8.2f} %  {verdict}{first}")


if __name__ == "__main__":
    main()
