"""``online-id check``: what a run can tell before any estimate (excitation, sampling, Cramér-Rao bound)."""

from __future__ import annotations

import argparse
from pathlib import Path

from online_id.cli.common import add_vehicle_argument, load_run, read_prior, vehicle_of
from online_id.cli.outputs import json_text
from online_id.errors import OnlineIdError


def add_parser(sub) -> None:
    p = sub.add_parser(
        "check",
        help="what a run can tell: excitation, sampling, Cramér-Rao bound, and what manoeuvre is missing",
        description="Before any estimate: sampling and gaps, channels, speed range, steering amplitude and"
        " spectrum by band, |a_y| range, the Cramér-Rao bound on each parameter (at the vehicle's prior or"
        " --prior, with the filter's sensor noise and with the noise measured from the log), and which"
        " manoeuvre or channel would determine what the run cannot. With no LOG, the built-in run is used.",
    )
    p.add_argument("log", nargs="?", type=Path, metavar="LOG", help="track-run CSV (default: built-in run)")
    add_vehicle_argument(p)
    p.add_argument("--prior", type=Path, metavar="FIT.json", help="linearise at a fit's values instead of the prior")
    p.add_argument("--json", type=Path, metavar="OUT.json", help="write the report as JSON")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from online_id.trust.check import check_run

    vehicle = vehicle_of(args)
    if args.json is not None and not args.json.parent.exists():
        raise OnlineIdError(f"{args.json}: folder {args.json.parent} does not exist")
    theta, where = vehicle.prior, f"the prior of {vehicle.name}"
    if args.prior is not None:
        theta, _ = read_prior(args.prior)
        where = str(args.prior)
    run_ = load_run(args.log, vehicle)
    if len(run_) < 2:
        raise OnlineIdError(f"{run_.source}: too short to check")
    report = check_run(run_, vehicle, theta, linearised_at=where)
    print(report.text())
    if args.json is not None:
        args.json.write_text(json_text(report.to_json_dict()), encoding="utf-8")  # strict: NaN and inf as null
        print(f"wrote {args.json}")
    return 0
