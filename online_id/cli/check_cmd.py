"""``online-id check``: what a run can tell before any estimate (excitation, sampling, Cramér-Rao bound)."""

from __future__ import annotations

import argparse
from pathlib import Path

from online_id.cli.common import add_intersample_argument, log_parent, printed_messages, source_options
from online_id.cli.estimate_cmd import input_paths
from online_id.cli.outputs import Outputs, json_text


def add_parser(sub) -> None:
    p = sub.add_parser(
        "check",
        parents=[log_parent()],
        description="Before any estimate: sampling and gaps, channels, speed range, steering amplitude and"
        " spectrum by band, |a_y| range, the Cramér-Rao bound on each parameter (at the vehicle's prior or"
        " --prior, with the filter's sensor noise and with the noise measured from the log), and which"
        " manoeuvre or channel would determine what the run cannot. With no LOG, the built-in run is used.",
    )
    p.add_argument("--prior", type=Path, metavar="FIT.json", help="linearise at a fit's values instead of the prior")
    add_intersample_argument(p)
    p.add_argument("--json", type=Path, metavar="OUT.json", help="write the report as JSON")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from online_id.workflows import check

    Outputs.check({"--json": args.json}, input_paths(args))
    report = check(args.log, vehicle=args.vehicle, prior=args.prior, resample=args.resample,
                   intersample=args.intersample, messages=printed_messages(), **source_options(args)).result
    print(report.text())
    outputs = Outputs()  # after the report is printed; strict JSON (null for infinite bounds), atomic
    if args.json is not None:
        outputs.write_text(args.json, json_text(report.to_json_dict()))
    return outputs.status()
