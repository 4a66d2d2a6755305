"""``online-id plot convergence``: estimates from several initial covariances and values, one figure."""

from __future__ import annotations

import argparse
from pathlib import Path

from online_id.cli import termination
from online_id.cli.common import (
    add_filter_arguments,
    log_parent,
    printed_messages,
    source_options,
)
from online_id.cli.estimate_cmd import input_paths
from online_id.cli.outputs import Outputs
from online_id.vehicle.parameters import PARAMETER_NAMES


def add_parser(sub) -> None:
    p = sub.add_parser("plot", description="Draw figures from estimation runs.")
    psub = p.add_subparsers(dest="figure", metavar="FIGURE")
    psub.required = True
    c = psub.add_parser(
        "convergence",
        parents=[log_parent()],
        help="how the estimates settle from different initial covariances and values",
        description="Run the filter once per initial-covariance scale (--p0-scale, multiplies the initial"
        " parameter variance) and per initial value (--init-scale, multiplies the prior, or the truth of a"
        " simulated run), and draw every parameter's trajectory with its ±1σ band. With --prior FIT.json the"
        " figure also shows the run from the vehicle's constructor prior, for comparison.",
    )
    add_filter_arguments(c)
    c.add_argument("--p0-scale", type=float, action="append", metavar="S",
                   help="initial parameter variance × S (repeatable; default: 1)")
    c.add_argument("--init-scale", type=float, action="append", metavar="F",
                   help="start every parameter at F × truth (simulated runs) or F × prior (repeatable)")
    c.add_argument("--out", type=Path, required=True, metavar="OUT.png")
    c.add_argument("--quiet", action="store_true", help="no progress bars")
    c.set_defaults(run=run_convergence)


def run_convergence(args: argparse.Namespace) -> int:
    from online_id.workflows import convergence

    Outputs.check({"--out": args.out}, input_paths(args))
    conv = convergence(args.log, vehicle=args.vehicle, filter=args.filter, prior=args.prior, channels=args.channels,
                       correct_every=args.correct_every, p0_scales=args.p0_scale or [1.0],
                       init_scales=args.init_scale or [], resample=args.resample, intersample=args.intersample,
                       progress=not args.quiet,
                       messages=printed_messages(), **source_options(args))
    runs, truth, channels = conv.result, conv.truth, conv.channels
    from online_id.plots.convergence import final_errors, plot_convergence

    head = f"{'case':<22}" + "".join(f"{n:>9}" for n in PARAMETER_NAMES)
    if truth is not None:
        print("final error against truth [%]:")
        print(head)
        for label, err in final_errors(runs, truth):
            print(f"{label:<22}" + "".join(f"{100 * e:>9.3f}" for e in err))
    else:
        print("final estimates:")
        print(head)
        for label, res in runs:
            print(f"{label:<22}" + "".join(f"{v:>9.4g}" for v in res.parameters.to_vector()))
    outputs = Outputs()  # after the results are printed
    outputs.write_with(args.out, lambda tmp: plot_convergence(
        runs, tmp, truth=truth, title=f"{args.filter.upper()} convergence over {conv.source} ({', '.join(channels)})"))
    return outputs.status(termination.exit_status() if conv.interrupted else 0)



