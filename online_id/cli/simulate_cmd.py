"""``online-id simulate``: write a simulated track run (CSV plus truth sidecar)."""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path

import numpy as np

from online_id.cli.outputs import Outputs
from online_id.effects import EFFECTS, parse_effect
from online_id.errors import OnlineIdError
from online_id.io.tracklog import truth_sidecar_path, write_track_run
from online_id.sim.maneuvers import MANEUVERS
from online_id.units import G
from online_id.vehicle.loader import load_vehicle


def add_parser(sub) -> None:
    p = sub.add_parser(
        "simulate",
        description="Simulate a test run (Haro's 0.2-4 Hz steering chirp by default) with sensor noise"
        " and write it as a track-run CSV, with the true parameters in a <name>.truth.json sidecar.",
    )
    p.add_argument("--out", required=True, type=Path, help="output CSV path")
    p.add_argument("--vehicle", default="haro2008", help="built-in vehicle name or TOML file (default: haro2008)")
    p.add_argument("--truth", default="track",
                   help="parameter set to simulate: 'constructor' or a [truth.*] set of the vehicle"
                   " (haro2008: track = Table 6, track60 = Table 5; default: track)")
    p.add_argument("--speed-kmh", type=float, default=80.0, help="constant speed [km/h] (default: 80)")
    p.add_argument("--speed-profile", metavar="T:KMH,...",
                   help="a speed that changes instead: time [s] : speed [km/h] pairs, e.g. 0:100,4:60,8:100"
                        " (braking from 100 to 60 km/h in 4 s, then traction back; a shape-preserving cubic between"
                        " them, held after the last)")
    p.add_argument("--duration", type=float, default=60.0, help="run length [s] (default: 60)")
    p.add_argument("--rate", type=float, default=1000.0, help="sample rate of the log [Hz] (default: 1000)")
    p.add_argument("--integration-rate", type=float, metavar="HZ",
                   help="integrate the car at this rate (e.g. 10000: a step of 0.1 ms, the steering a cubic"
                   " between the fine samples) and log every k-th fine sample, as a logger samples a continuous"
                   " car; 0: at the log's rate with the steering held over each sample (default: 10000,"
                   " online_id.sim.simulator.INTEGRATION_RATE_HZ)")
    p.add_argument("--amplitude-deg", type=float, default=22.0,
                   help="steering-wheel amplitude [deg] (default: 22)")
    p.add_argument("--maneuver", choices=MANEUVERS, default="chirp",
                   help="chirp: 0.2-4 Hz sweep; step: ramp to the amplitude at 1 s; sine: see --frequency")
    p.add_argument("--frequency", type=float, default=0.2, help="sine frequency [Hz] (default: 0.2)")
    p.add_argument("--seed", type=int, default=0, help="noise seed (default: 0)")
    p.add_argument("--no-noise", action="store_true", help="exact outputs, no sensor noise")
    p.add_argument("--lateral-velocity", action="store_true",
                   help="also log the lateral velocity at the centre of gravity [m/s] (an INS's or an optical sideslip"
                        " sensor's, 0.02 m/s noise): the column lateral_velocity")
    p.add_argument("--longitudinal-acceleration", action="store_true",
                   help="also log the longitudinal acceleration at the centre of gravity [m/s²] as a body-fixed"
                        " accelerometer reads it (dV/dt − v_y·r, 0.05 m/s² noise): the column"
                        " longitudinal_acceleration")
    p.add_argument("--effect", action="append", default=[], metavar="NAME=VALUE",
                   help="give the simulated car an unmodelled effect (repeatable): "
                   + "; ".join(f"{name}={cls.syntax}" for name, cls in EFFECTS.items()))
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from online_id.sim.maneuvers import SpeedProfile
    from online_id.sim.simulator import SensorNoise, simulate
    from online_id.workflows.inputs import check_effects_act

    if args.speed_kmh <= 0:
        raise OnlineIdError(f"--speed-kmh must be positive, got {args.speed_kmh}")
    speed = args.speed_kmh / 3.6
    if args.speed_profile is not None:
        try:
            speed = SpeedProfile.parse(args.speed_profile)
        except ValueError as exc:
            raise OnlineIdError(f"--speed-profile: {exc}") from None
    if args.duration <= 0 or args.rate <= 0:
        raise OnlineIdError("--duration and --rate must be positive")
    if args.integration_rate is not None and not args.integration_rate >= 0:
        raise OnlineIdError(f"--integration-rate must be positive (or 0), got {args.integration_rate}")
    fine = {} if args.integration_rate is None else {"integration_rate_hz": args.integration_rate or None}
    Outputs.check({"--out": args.out, "its truth sidecar": truth_sidecar_path(args.out)},
                  {"--vehicle": Path(args.vehicle)})
    vehicle = load_vehicle(args.vehicle)
    theta = vehicle.truth(args.truth)
    effects = [parse_effect(e) for e in args.effect]
    written = ("yaw_rate", "roll_angle", "roll_rate", "lateral_acceleration",
               *(("lateral_velocity",) if args.lateral_velocity else ()))
    # (an INS's misalignment on a log without the lateral velocity would act on nothing)
    check_effects_act(effects, written, "the simulated log" + ("" if args.lateral_velocity else
                                                              " (add --lateral-velocity to log lateral_velocity)"))
    sim = simulate(
        vehicle, theta,
        duration_s=args.duration, rate_hz=args.rate, speed_mps=speed,
        maneuver=args.maneuver, amplitude_rad=np.deg2rad(args.amplitude_deg),
        noise=SensorNoise.none() if args.no_noise else SensorNoise(), seed=args.seed,
        frequency_hz=args.frequency, truth_name=args.truth, effects=effects,
        lateral_velocity=args.lateral_velocity, longitudinal_acceleration=args.longitudinal_acceleration, **fine,
    )
    outputs = Outputs(announce=False)
    outputs.write_with(args.out, lambda tmp: write_track_run(replace(sim.run, meta={}), tmp))
    if sim.run.meta:
        outputs.write_text(truth_sidecar_path(args.out), json.dumps(sim.run.meta, indent=2) + "\n")
    if outputs.failed:
        return outputs.status()
    peak_ay = np.abs(sim.outputs[:, 3]).max()
    peak_r = np.rad2deg(np.abs(sim.outputs[:, 0]).max())
    integrated = sim.run.meta.get("integration_rate_hz")
    print(f"wrote {args.out} ({len(sim.run)} samples, {args.duration:g} s at {args.rate:g} Hz"
          + (f", integrated at {integrated:g} Hz" if integrated else "") + f") and {truth_sidecar_path(args.out)}")
    at = (f"at {args.speed_kmh:g} km/h" if args.speed_profile is None else
          f"at {sim.run.speed.min() * 3.6:.0f}-{sim.run.speed.max() * 3.6:.0f} km/h ({args.speed_profile})")
    print(f"  vehicle {vehicle.name}, truth '{args.truth}', {args.maneuver} {args.amplitude_deg:g} deg"
          f" {at}; peak |a_y| {peak_ay:.2f} m/s² ({peak_ay / G:.3f} g),"
          f" peak |yaw rate| {peak_r:.1f} deg/s")
    if not isinstance(speed, float):
        dV = speed.acceleration(sim.run.time)
        print(f"  braking to {-dV.min() / G:.2f} g, traction to {dV.max() / G:.2f} g")
    for e in args.effect:
        print(f"  with effect {e}")
    return 0
