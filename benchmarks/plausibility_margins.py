"""The margins of the channel-relation checks (online_id/trust/relations.py): the low-passed correlations of the
three turning relations (a_y ~ V·r, r ~ r_ss(δH), a_y ~ V·r_ss(δH)) and of roll ~ a_y on clean simulated runs,
the real logs (race car, RAV4), the independent simulator, and runs with one channel that does not belong;
then each run's verdict (checks failed, channels named).

    python benchmarks/plausibility_margins.py [--no-independent]
"""

from __future__ import annotations

import argparse
from dataclasses import replace

import _checkout  # noqa: F401
import numpy as np

from online_id.io.tracklog import read_track_run
from online_id.sim.simulator import simulate
from online_id.trust.plausibility import judge_run
from online_id.trust.relations import measure
from online_id.vehicle.loader import load_vehicle

SHARED = _checkout.Path(_checkout.ROOT).parent / "shared"
if not (SHARED / "realdata").is_dir():
    SHARED = _checkout.Path("/work/shared")
REVS = SHARED / "realdata" / "revs_250lm" / "revs_250lm_laps_0-400s.csv"
RAV4 = SHARED / "realdata" / "comma2k19_rav4"


def clean_runs():
    haro = load_vehicle("haro2008")
    for maneuver in ("chirp", "step", "sine"):
        for truth in ("track", "track60", "constructor"):
            for kmh in (60, 80):
                yield (f"sim {maneuver} {truth} {kmh} km/h 60 s", haro,
                       simulate(haro, haro.truth(truth), speed_mps=kmh / 3.6, maneuver=maneuver, seed=1).run)
    yield "sim chirp 20 s 1 kHz", haro, simulate(haro, haro.truth("track"), duration_s=20, seed=0).run
    yield "sim chirp 20 s 100 Hz", haro, simulate(haro, haro.truth("track"), duration_s=20, rate_hz=100, seed=0).run
    yield ("sim chirp 3 deg 30 s", haro, simulate(haro, haro.truth("track"), duration_s=30, rate_hz=200,
                                                  amplitude_rad=np.deg2rad(3.0), seed=4).run)
    from online_id.effects import parse_effect

    for effect in ("tire_saturation=0.6", "sensor_delay=yaw_rate:0.03", "accelerometer_gravity=1",
                   "sensor_bias=lateral_acceleration:0.3"):
        yield (f"sim chirp with {effect}", haro,
               simulate(haro, haro.truth("track"), duration_s=30, rate_hz=200, seed=2,
                        effects=[parse_effect(effect)]).run)


def real_runs():
    yield "race car (revs_250lm)", load_vehicle("revs_250lm"), read_track_run(REVS)
    from online_id.drivers.sources import load_run

    rav4 = load_run(RAV4 / "rav4_highway_60s.log", dbc=RAV4 / "toyota_rav4_2017_chassis.dbc",
                    signals="toyota_rav4_2017").run
    yield "RAV4 CAN log (decoded)", load_vehicle("rav4_2017"), rav4


def independent_runs():
    import sys

    sys.path.insert(0, _checkout.ROOT)
    from tests.independent_sim import simulate_mb, vehicle_for

    for car in (1, 2, 3):
        for maneuver in ("chirp", "steps", "sines"):
            yield (f"CommonRoad MB car {car} {maneuver}", vehicle_for(car),
                   simulate_mb(car, maneuver, duration_s=20.0, rate_hz=100.0, seed=car))


def hostile(run):
    """One channel that does not belong, as a wrong column or a broken sensor makes it."""
    rng = np.random.default_rng(7)

    def noise(v):
        return rng.normal(np.mean(v), np.std(v), len(v))

    n = len(run)
    out = {
        "a_y noise": replace(run, lateral_acceleration=noise(run.lateral_acceleration)),
        "a_y reversed": replace(run, lateral_acceleration=run.lateral_acceleration[::-1].copy()),
        "a_y shifted a third": replace(run, lateral_acceleration=np.roll(run.lateral_acceleration, n // 3)),
        "a_y zero": replace(run, lateral_acceleration=np.zeros(n)),
        "yaw noise": replace(run, yaw_rate=noise(run.yaw_rate)),
        "yaw reversed": replace(run, yaw_rate=run.yaw_rate[::-1].copy()),
        "yaw zero (dead)": replace(run, yaw_rate=np.zeros(n)),
        "yaw constant 0.01": replace(run, yaw_rate=np.full(n, 0.01)),
        "speed noise": replace(run, speed=np.abs(noise(run.speed))),
        "steering zero": replace(run, steering_wheel_angle=np.zeros(n)),
        "steering noise": replace(run, steering_wheel_angle=noise(run.steering_wheel_angle)),
    }
    if run.roll_rate is not None:
        out["yaw swapped with roll rate"] = replace(run, yaw_rate=run.roll_rate, roll_rate=run.yaw_rate)
    if run.roll_angle is not None:
        out["roll noise"] = replace(run, roll_angle=noise(run.roll_angle))
        out["roll reversed"] = replace(run, roll_angle=run.roll_angle[::-1].copy())
        out["roll zero"] = replace(run, roll_angle=np.zeros(n))
    return out


def row(name, vehicle, run) -> str:
    m = measure(run.time, run.steering_wheel_angle, run.speed, run.yaw_rate, run.lateral_acceleration,
                run.roll_angle, vehicle.known, vehicle.prior)
    cells = [f"{m[k].correlation:+.2f}" if m[k] is not None else "  -  " for k in ("ay_vr", "yaw_steer", "ay_steer",
                                                                                   "roll_ay")]
    spreads = f"{m['ay_vr'].spread_b:.3f} {m['ay_steer'].spread_b:.3f} {m['ay_vr'].spread_a:.3f}"
    report = judge_run(run, vehicle)
    failed = ", ".join(f"{r.check}({r.channel})" for r in report.failures) or "-"
    return f"{name:<42} {' '.join(cells)}   {spreads}   {m['cornering_s']:6.1f}  {failed}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--no-independent", action="store_true", help="skip the CommonRoad runs (slow)")
    args = parser.parse_args()
    print(f"{'run':<42} ay~Vr r~rss ay~Vrss φ~ay   sd(Vr) sd(Vrss) sd(ay) [m/s²]  corner[s]  failed checks")
    sources = [clean_runs(), real_runs()] + ([] if args.no_independent else [independent_runs()])
    hostile_bases = {}
    for source in sources:
        for name, vehicle, run in source:
            print(row(name, vehicle, run), flush=True)
            if name.startswith(("sim chirp 20 s 1 kHz", "race car", "RAV4", "CommonRoad MB car 2 chirp")):
                hostile_bases[name] = (vehicle, run)
    for base, (vehicle, run) in hostile_bases.items():
        print(f"-- {base}, one channel that does not belong")
        for name, bad in hostile(run).items():
            print(row(f"  {name}", vehicle, bad), flush=True)


if __name__ == "__main__":
    main()
