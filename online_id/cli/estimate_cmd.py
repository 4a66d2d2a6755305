"""``online-id estimate``: run the online filter over a track-run log (or the built-in run)."""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from online_id.cli.bus_args import add_dbc_arguments, dbc_and_map
from online_id.cli.common import (
    add_filter_arguments,
    add_vehicle_argument,
    load_run,
    parse_channels,
    read_prior,
    run_truth,
    vehicle_of,
)
from online_id.errors import OnlineIdError
from online_id.vehicle.parameters import PARAMETER_NAMES


def add_parser(sub) -> None:
    p = sub.add_parser(
        "estimate",
        help="estimate the 8 parameters online from a track-run log",
        description="Run the augmented-state EKF or UKF over a track-run CSV, sample by sample, and print"
        " prior, estimate, 1σ (and truth for simulated runs). With no LOG, a built-in simulated run is used."
        " A CAN log (candump .log, .asc, .blf, ...) is decoded with --dbc and --signals.",
    )
    p.add_argument("log", nargs="?", type=Path, metavar="LOG", help="track-run CSV (default: built-in run)")
    add_vehicle_argument(p)
    add_filter_arguments(p)
    add_dbc_arguments(p)
    p.add_argument("--json", type=Path, metavar="OUT.json", help="write the result as JSON")
    p.add_argument("--trace", type=Path, metavar="OUT.csv", help="write the estimate's time history as CSV")
    p.add_argument("--plot", type=Path, metavar="OUT.png", help="draw the convergence of each parameter")
    p.add_argument("--polish", action=argparse.BooleanOptionalAction, default=None,
                   help="after the filter, polish its estimate by a batch output-error fit over the whole log"
                   " (Gauss-Newton, reaches the Cramér-Rao bound; the filter's own estimate goes to 'online' in"
                   " --json). Default: on for a track-run CSV or the built-in run, off for a CAN log")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(run=run)


def filter_config(args):
    """The FilterConfig the flags ask for."""
    from online_id.filters import FilterConfig

    config = FilterConfig()
    if getattr(args, "correct_every", None) is not None:
        if args.correct_every < 1:
            raise OnlineIdError("--correct-every must be at least 1")
        config = replace(config, correct_every=args.correct_every)
    return config


def run(args: argparse.Namespace) -> int:
    from online_id.estimation import make_estimator, run_estimator
    from online_id.samples import samples_from_run

    vehicle = vehicle_of(args)
    for out in (args.json, args.trace, args.plot):
        if out is not None and not out.parent.exists():
            raise OnlineIdError(f"{out}: folder {out.parent} does not exist")
    prior, prior_rel = (None, None) if args.prior is None else read_prior(args.prior)
    estimator_for = lambda: make_estimator(vehicle, args.filter, prior=prior,  # noqa: E731
                                           prior_relative_std=prior_rel, config=filter_config(args))
    if is_can_log(args):
        if args.polish:
            raise OnlineIdError("--polish needs a track-run CSV (a CAN log is streamed, not held as one run)")
        result, source = estimate_can_log(args, estimator_for())
        channels = result.channels
        label = str(args.log)
    else:
        source = None
        run_ = load_run(args.log, vehicle)
        channels = parse_channels(args.channels, run_)
        result = run_estimator(estimator_for(), samples_from_run(run_, tuple(channels)), total=len(run_),
                               progress=not args.quiet, source=run_.source, truth=run_truth(run_),
                               channels=channels)
        label = run_.source
        if args.polish is not False and not result.interrupted:
            polish_result(result, vehicle, run_, args)
    if prior is not None:
        result.cross_check = cross_check(result, prior, prior_rel)
    write_outputs(result, args)
    print(f"{result.filter.upper()} over {label}: {result.samples} samples in {result.wall_s:.2f} s"
          f" ({result.sim_seconds / max(result.wall_s, 1e-9):.1f}x real time); channels: {', '.join(channels)}")
    print(result.table())
    print(result.events_summary())
    if result.cross_check:
        print(f"cross-check against {args.prior} (difference in combined σ; |z| > 3 disagrees):")
        for n, c in result.cross_check.items():
            flag = "  DISAGREES" if c["disagree"] else ""
            print(f"  {n:<4} filter {c['estimate']:.6g}  fit {c['fit']:.6g}  z {c['z']:+.2f}{flag}")
    missing = [n for n, ok in result.informed.items() if not ok]
    if missing:
        print(f"not informed by this run (σ above half its prior σ; kept near the prior): {', '.join(missing)}")
    if source is not None:
        for line in source.problems():
            print(f"online-id: warning: {label}: {line}", file=sys.stderr)
    if result.interrupted:
        print("interrupted: the results above are those reached so far", file=sys.stderr)
        return 130
    return 0


def polish_result(result, vehicle, run_, args) -> None:
    """The batch polish of the filter's estimate (online_id.fit.polish), reported on stdout/stderr."""
    from online_id.fit.polish import POLISH_BURN_IN_S, polish_estimate

    config = filter_config(args)
    problem = polish_estimate(result, vehicle, run_, config.measurement_std, burn_in_s=POLISH_BURN_IN_S,
                              prior_log_std_floor=config.prior_log_std_floor)
    if problem:
        print(f"online-id: warning: {run_.source}: {problem}", file=sys.stderr)
        return
    p = result.polish
    print(f"polished the {result.filter.upper()} estimate by a batch fit over the whole run: {p['iterations']}"
          f" evaluations, {p['wall_s']:.2f} s; covariance × {p['covariance_inflation']:.2f} for correlated residuals")


def is_can_log(args) -> bool:
    """A CAN log when --dbc/--signals is given or LOG is not a .csv."""
    if args.log is None:
        return False
    return bool(args.dbc or args.signals) or args.log.suffix.lower() != ".csv"


def estimate_can_log(args, estimator):
    from drivers.can_log import CanLogSource
    from online_id.estimation import run_estimator

    if not (args.dbc or args.signals):
        raise OnlineIdError(f"{args.log}: not a .csv track run; for a CAN log give --dbc and --signals")
    db, smap = dbc_and_map(args)
    source = CanLogSource(args.log, db, smap)
    channels = [c for c in ("yaw_rate", "roll_angle", "roll_rate", "lateral_acceleration") if c in smap.signals]
    if args.channels:
        wanted = [c.strip() for c in args.channels.split(",")]
        bad = [c for c in wanted if c not in channels]
        if bad:
            raise OnlineIdError(f"--channels: {', '.join(bad)} not mapped by {smap.source}")
        channels = wanted
        estimator.config = replace(estimator.config, measurement_std={
            c: v for c, v in estimator.config.measurement_std.items() if c in channels})
    result = run_estimator(estimator, source, progress=False, source=str(args.log), channels=channels)
    result.source_report = {"ended_by": source.ended_by, "frames": source.report()}
    return result, source


def cross_check(result, prior, prior_rel) -> dict:
    """Per parameter: the filter's final value against the prior's (a fit's), in combined σ."""
    out = {}
    for i, n in enumerate(PARAMETER_NAMES):
        est, sd = float(result.parameters.to_vector()[i]), float(result.std[i])
        fit = float(prior.to_vector()[i])
        fit_sd = fit * float(prior_rel[i]) if np.isfinite(prior_rel[i]) else float("inf")
        z = (est - fit) / np.hypot(sd, fit_sd)
        out[n] = {"estimate": est, "fit": fit, "fit_std": fit_sd if np.isfinite(fit_sd) else None,
                  "z": float(z), "disagree": bool(abs(z) > 3)}
    return out


def write_outputs(result, args) -> None:
    if args.json is not None:
        result.write_json(args.json)
        print(f"wrote {args.json}")
    if args.trace is not None:
        result.trace.write_csv(args.trace)
        print(f"wrote {args.trace}")
    if getattr(args, "plot", None) is not None:
        from online_id.plots.convergence import plot_convergence

        plot_convergence([(result.filter.upper(), result)], args.plot, truth=result.truth,
                         title=f"{result.filter.upper()} estimate over {result.source}")
        print(f"wrote {args.plot}")
