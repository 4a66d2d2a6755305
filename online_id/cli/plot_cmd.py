"""``online-id plot convergence``: estimates from several initial covariances and values, one figure."""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

from online_id.cli import signals
from online_id.cli.common import (
    add_filter_arguments,
    add_resample_argument,
    add_source_arguments,
    add_vehicle_argument,
    load_run,
    parse_channels,
    read_prior,
    run_truth,
    vehicle_of,
)
from online_id.cli.estimate_cmd import filter_config, input_paths
from online_id.cli.outputs import Outputs
from online_id.errors import OnlineIdError
from online_id.stream.samples import samples_from_run
from online_id.vehicle.parameters import PARAMETER_NAMES


def add_parser(sub) -> None:
    p = sub.add_parser("plot", help="draw figures", description="Draw figures from estimation runs.")
    psub = p.add_subparsers(dest="figure", metavar="FIGURE")
    psub.required = True
    c = psub.add_parser(
        "convergence",
        help="how the estimates settle from different initial covariances and values",
        description="Run the filter once per initial-covariance scale (--p0-scale, multiplies the initial"
        " parameter variance) and per initial value (--init-scale, multiplies the prior, or the truth of a"
        " simulated run), and draw every parameter's trajectory with its ±1σ band. With --prior FIT.json the"
        " figure also shows the run from the vehicle's constructor prior, for comparison.",
    )
    c.add_argument("log", nargs="?", type=Path, metavar="LOG",
                   help="track-run CSV, CAN log or MDF file (default: built-in run)")
    add_vehicle_argument(c)
    add_source_arguments(c)
    add_resample_argument(c)
    add_filter_arguments(c)
    c.add_argument("--p0-scale", type=float, action="append", metavar="S",
                   help="initial parameter variance × S (repeatable; default: 1)")
    c.add_argument("--init-scale", type=float, action="append", metavar="F",
                   help="start every parameter at F × truth (simulated runs) or F × prior (repeatable)")
    c.add_argument("--out", type=Path, required=True, metavar="OUT.png")
    c.add_argument("--quiet", action="store_true", help="no progress bars")
    c.set_defaults(run=run_convergence)


def run_convergence(args: argparse.Namespace) -> int:
    from online_id.estimation import make_estimator, run_estimator

    vehicle = vehicle_of(args)
    Outputs.check({"--out": args.out}, input_paths(args))
    prior, prior_rel = (None, None) if args.prior is None else read_prior(args.prior)
    run_ = load_run(args.log, vehicle, args)
    channels = parse_channels(args.channels, run_)
    truth = run_truth(run_)
    base = filter_config(args)
    p0_scales = args.p0_scale or [1.0]
    init_scales = args.init_scale or []
    if any(s <= 0 for s in p0_scales + init_scales):
        raise OnlineIdError("--p0-scale and --init-scale must be positive")
    centre = truth or prior or vehicle.prior
    cases = [(f"P0 × {s:g}" + (f" from {args.prior.name}" if prior else ""), replace(base, p0_scale=s), None)
             for s in p0_scales]
    cases += [(f"start {f:g} × {'truth' if truth else 'prior'}", base, centre.scaled(f)) for f in init_scales]
    if prior is not None:  # the reference: the same filter from the vehicle's constructor prior
        cases.append(("constructor prior", base, "constructor"))
    runs = []
    for label, config, initial in cases:
        if initial == "constructor":
            est = make_estimator(vehicle, args.filter, config=config)
        else:
            est = make_estimator(vehicle, args.filter, prior=prior, prior_relative_std=prior_rel, initial=initial,
                                 config=config)
        print(f"running {label} ...", file=sys.stderr)
        res = run_estimator(est, samples_from_run(run_, tuple(channels)), total=len(run_),
                            progress=not args.quiet, source=run_.source, truth=truth, channels=channels)
        runs.append((label, res))
        if res.interrupted:
            break
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
        runs, tmp, truth=truth, title=f"{args.filter.upper()} convergence over {run_.source} ({', '.join(channels)})"))
    return outputs.status(signals.exit_status() if any(r.interrupted for _, r in runs) else 0)



