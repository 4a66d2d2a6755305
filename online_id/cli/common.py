"""Pieces several sub-commands share: the built-in run, reading a prior, channel selection."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from online_id.errors import OnlineIdError
from online_id.io.tracklog import TrackRun
from online_id.stream.samples import MEASURED_CHANNELS
from online_id.util.stages import stage
from online_id.vehicle.loader import Vehicle, load_vehicle
from online_id.vehicle.parameters import PARAMETER_NAMES, Parameters

BUILTIN_RUN = "Haro's 0.2-4 Hz chirp, 22 deg, 80 km/h, 60 s at 1 kHz, Table 6 car, seed 0"


def add_vehicle_argument(p) -> None:
    p.add_argument("--vehicle", default="haro2008", help="built-in vehicle name or TOML file (default: haro2008)")


def add_filter_arguments(p) -> None:
    p.add_argument("--filter", choices=("ekf", "ukf"), default="ekf", help="online filter (default: ekf)")
    p.add_argument("--prior", type=Path, metavar="FIT.json",
                   help="start from a fit's (or an earlier estimate's) values and standard deviations")
    p.add_argument("--channels", metavar="LIST",
                   help="comma-separated measured channels to use"
                   f" (default: all present of {','.join(MEASURED_CHANNELS)})")
    p.add_argument("--correct-every", type=int, metavar="K",
                   help="correct every K-th sample with the block means of the K samples (default: 20)")


def add_source_arguments(p) -> None:
    """LOG's decoding: --dbc/--signals for CAN and MDF logs, --can-channel (drivers/sources.py reads them)."""
    from online_id.cli.bus_args import add_dbc_arguments

    add_dbc_arguments(p)
    p.add_argument("--can-channel", metavar="CH",
                   help="CAN channel of a log to use: can0, can1, ... (or a number, counted from 0; 'any' for"
                   " all; default: the signal map's, else all)")


def add_resample_argument(p) -> None:
    p.add_argument("--resample", type=float, metavar="HZ",
                   help="put a decoded log on an even grid at HZ by linear interpolation (a CAN log's trigger frames"
                   " arrive unevenly; the fit and the diagnosis need one step); refuses across dropouts over 0.1 s")


def source_options(args) -> dict:
    """Keywords for drivers.sources.open_source/load_run from the flags of add_source_arguments."""
    return {"dbc": getattr(args, "dbc", None), "signals": getattr(args, "signals", None),
            "can_channel": getattr(args, "can_channel", None)}


@stage("reading the log")
def load_run(log: Path | None, vehicle: Vehicle, args=None) -> TrackRun:
    """The log at ``log`` (any source drivers/sources.py reads, decoded with ``args``' --dbc, --signals,
    --can-channel), or the built-in simulated run when ``log`` is None."""
    if log is None:
        from online_id.sim.simulator import simulate

        print(f"no LOG given: using the built-in run ({BUILTIN_RUN})", file=sys.stderr)
        if vehicle.name != "haro2008" and "track" not in vehicle.truths:
            raise OnlineIdError(f"the built-in run needs a [truth.track] set in {vehicle.source}")
        run = simulate(vehicle, vehicle.truth("track"), truth_name="track", seed=0).run
        run.source = "the built-in run"
        return run
    from drivers.sources import load_run as load_any

    loaded = load_any(log, **source_options(args) if args is not None else {})
    run, warnings = loaded.run, []
    if loaded.decode is not None:  # a log decoded into a run: what the source and the decoding saw
        warnings = loaded.problems()
        print(f"{log}: decoded {len(run)} samples ({', '.join(run.channels[1:])})", file=sys.stderr)
    if getattr(args, "resample", None):
        from drivers.resample import resample_run

        run, info = resample_run(run, args.resample)
        print(f"{log}: resampled {info['samples_before']} samples to {info['samples']} at {args.resample:g} Hz"
              f" (longest interval interpolated {1e3 * info['longest_interval_s']:.3g} ms)", file=sys.stderr)
    for warning in warnings + run.sampling.warnings():
        print(f"online-id: warning: {log}: {warning}", file=sys.stderr)
    return run


def run_truth(run: TrackRun) -> Parameters | None:
    truth = run.truth
    if not truth:
        return None
    try:
        return Parameters(**{n: float(truth[n]) for n in PARAMETER_NAMES})
    except (KeyError, TypeError, ValueError):
        return None


def read_prior(path: Path) -> tuple[Parameters, np.ndarray]:
    """Values and relative 1σ from a JSON with ``{"parameters": {"Mzz": {"value": v, "std": s}, ...}}``.

    A ``null`` std (a parameter the fit could not determine) gives NaN: the estimator then uses
    the vehicle's prior σ for it.
    """
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise OnlineIdError(f"{path}: no such prior file") from None
    except (OSError, ValueError) as exc:
        raise OnlineIdError(f"{path}: not a readable JSON prior: {exc}") from None
    params = data.get("parameters") if isinstance(data, dict) else None
    if not isinstance(params, dict):
        raise OnlineIdError(f"{path}: missing key 'parameters'")
    values, rel = [], []
    for n in PARAMETER_NAMES:
        entry = params.get(n)
        if not isinstance(entry, dict) or "value" not in entry or "std" not in entry:
            raise OnlineIdError(f"{path}: missing key parameters.{n} with 'value' and 'std'")
        v, s = entry["value"], entry["std"]
        if not (isinstance(v, (int, float)) and v > 0 and (s is None or isinstance(s, (int, float)) and s > 0)):
            raise OnlineIdError(f"{path}: parameters.{n}: value and std must be positive numbers, got {v!r}, {s!r}")
        values.append(float(v))
        rel.append(np.nan if s is None else float(s) / float(v))
    return Parameters.from_vector(values), np.array(rel)


def parse_channels(text: str | None, run: TrackRun) -> list[str]:
    present = [c for c in MEASURED_CHANNELS if getattr(run, c) is not None]
    if text is None:
        return present
    wanted = [c.strip() for c in text.split(",") if c.strip()]
    for c in wanted:
        if c not in MEASURED_CHANNELS:
            raise OnlineIdError(f"--channels: unknown channel {c!r}; choose from {', '.join(MEASURED_CHANNELS)}")
        if c not in present:
            raise OnlineIdError(f"--channels: {c} is not in {run.source}")
    if not wanted:
        raise OnlineIdError("--channels: no channel given")
    return wanted


def vehicle_of(args) -> Vehicle:
    return load_vehicle(args.vehicle)
