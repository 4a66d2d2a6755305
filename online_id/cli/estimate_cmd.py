"""``online-id estimate``: run the online filter over a track-run log (or the built-in run)."""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from online_id.cli import library_warnings, signals
from online_id.cli.common import (
    add_filter_arguments,
    add_source_arguments,
    add_vehicle_argument,
    load_run,
    parse_channels,
    read_prior,
    run_truth,
    source_options,
    vehicle_of,
)
from online_id.cli.effect_args import add_effect_arguments, extra_state_lines, filter_effects_of, offsets_of
from online_id.cli.outputs import Outputs
from online_id.cli.plausibility_args import add_plausibility_argument, check_run, checked_stream
from online_id.cli.prior_args import add_prior_arguments, parse_fix
from online_id.errors import OnlineIdError
from online_id.trust.consistency import verdict_line
from online_id.vehicle.parameters import PARAMETER_NAMES


def add_parser(sub) -> None:
    p = sub.add_parser(
        "estimate",
        help="estimate the 8 parameters online from a track-run log",
        description="Run the augmented-state EKF or UKF over a track-run CSV, sample by sample, and print"
        " prior, estimate, 1σ (and truth for simulated runs). With no LOG, a built-in simulated run is used."
        " A CAN log (candump .log, .asc, .blf, .trc, .mf4, ...) is decoded with --dbc and --signals (default:"
        " online-id's own frames); an MDF file of decoded signals is read by column name or by --signals.",
    )
    p.add_argument("log", nargs="?", type=Path, metavar="LOG",
                   help="track-run CSV or parquet, CAN log or MDF file (default: built-in run)")
    add_vehicle_argument(p)
    add_filter_arguments(p)
    add_source_arguments(p)
    add_prior_arguments(p)
    add_plausibility_argument(p)
    add_effect_arguments(p)
    p.add_argument("--json", type=Path, metavar="OUT.json", help="write the result as JSON")
    p.add_argument("--trace", type=Path, metavar="OUT.csv", help="write the estimate's time history as CSV")
    p.add_argument("--plot", type=Path, metavar="OUT.png", help="draw the convergence of each parameter")
    p.add_argument("--polish", action=argparse.BooleanOptionalAction, default=None,
                   help="after the filter, polish its estimate by a batch output-error fit over the whole log"
                   " (Gauss-Newton, reaches the Cramér-Rao bound; the filter's own estimate goes to 'online' in"
                   " --json). Default: on for a track-run CSV or the built-in run, off for a CAN log")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    add_strict_argument(p)
    p.set_defaults(run=run)


def add_strict_argument(p) -> None:
    p.add_argument("--strict", action="store_true",
                   help="exit 3 when the run is judged inconsistent with the model (after writing the outputs)")


def strict_status(consistency: dict | None, args) -> int:
    """3 under --strict when the verdict is inconsistent, else 0."""
    if getattr(args, "strict", False) and consistency is not None and not consistency["consistent"]:
        return 3
    return 0


def filter_config(args):
    """The FilterConfig the flags ask for."""
    from online_id.filters import FilterConfig

    config = FilterConfig()
    if getattr(args, "correct_every", None) is not None:
        if args.correct_every < 1:
            raise OnlineIdError("--correct-every must be at least 1")
        config = replace(config, correct_every=args.correct_every)
    if getattr(args, "keep_prior_std", False):
        config = replace(config, prior_log_std_floor=0.0)
    return config


def run(args: argparse.Namespace) -> int:
    from online_id.estimation import make_estimator, run_estimator
    from online_id.stream.samples import samples_from_run

    vehicle = vehicle_of(args)
    Outputs.check({"--json": args.json, "--trace": args.trace, "--plot": args.plot}, input_paths(args))
    prior, prior_rel = (None, None) if args.prior is None else read_prior(args.prior)
    fixed = parse_fix(args.fix, prior or vehicle.prior)
    effects = filter_effects_of(args, vehicle.known)

    notes: list[str] = []  # printed with the results, so that an input error stays the only line

    def estimator_for(config, channels):
        estimator = make_estimator(vehicle, args.filter, prior=prior, prior_relative_std=prior_rel, config=config,
                                   fixed=fixed, effects=effects, offsets=offsets_of(args, channels), channels=channels)
        notes.extend(estimator.prior_spread.notes())
        return estimator

    if args.log is not None:
        result, warnings = estimate_source(args, estimator_for, vehicle, effects)
        channels = result.channels
        label = str(args.log)
    else:
        warnings = []
        run_ = load_run(args.log, vehicle)
        channels = parse_channels(args.channels, run_)
        estimator = estimator_for(filter_config(args), channels)  # a bad --effect is an error before any check
        check_run(run_, vehicle, args)
        result = run_estimator(estimator, samples_from_run(run_, tuple(channels)),
                               total=len(run_),
                               progress=not args.quiet, source=run_.source, truth=run_truth(run_),
                               channels=channels)
        label = run_.source
        if polish_wanted(args, whole_run=True) and not result.interrupted:
            polish_result(result, vehicle, run_, args, effects)
    if prior is not None:
        result.cross_check = cross_check(result, prior, prior_rel)
    print(f"{result.filter.upper()} over {label}: {result.samples} samples in {result.wall_s:.2f} s"
          f" ({result.sim_seconds / max(result.wall_s, 1e-9):.1f}x real time); channels: {', '.join(channels)}")
    print(result.table())
    print(result.events_summary())
    for line in extra_state_lines(result.extra_states):
        print(line)
    if result.cross_check:
        print(f"cross-check against {args.prior} (difference in combined σ; |z| > 3 disagrees):")
        for n, c in result.cross_check.items():
            flag = "  DISAGREES" if c["disagree"] else ""
            print(f"  {n:<4} filter {c['estimate']:.6g}  fit {c['fit']:.6g}  z {c['z']:+.2f}{flag}")
    missing = [n for n, ok in result.informed.items() if not ok and n not in result.fixed]
    if missing:
        print(f"not informed by this run (σ above half its prior σ): {', '.join(missing)}")
    print(verdict_line(result.consistency))
    for note in notes:
        print(f"online-id: note: {note}", file=sys.stderr)
    for line in warnings:
        print(f"online-id: warning: {label}: {line}", file=sys.stderr)
    outputs = write_outputs(result, args)  # after the results are printed: a failed write loses nothing
    if result.interrupted:
        print(f"interrupted ({signals.signal_name()}): the results above are those reached so far", file=sys.stderr)
        return outputs.status(signals.exit_status())
    return outputs.status(strict_status(result.consistency, args))


def polish_wanted(args, whole_run: bool) -> bool:
    """Whether to polish: on by default for a whole track run (CSV or the built-in run), with or without
    effects (the polish fits theirs with the 8); --polish where it cannot apply (a streamed CAN log, offsets
    or fixed parameters, which the batch polish does not model) is an error."""
    extended = bool(getattr(args, "offsets", False) or getattr(args, "fix", None))
    if args.polish:
        if not whole_run:
            raise OnlineIdError("--polish needs a track-run CSV (a CAN log is streamed, not held as one run)")
        if extended:
            raise OnlineIdError("--polish fits the 8 parameters and the effects' own: it cannot be combined with"
                                " --offsets or --fix")
        return True
    return args.polish is None and whole_run and not extended


def polish_result(result, vehicle, run_, args, effects=()) -> None:
    """The batch polish of the filter's estimate (online_id.batchfit.polish), reported on stdout/stderr."""
    from online_id.batchfit.polish import POLISH_BURN_IN_S, polish_estimate

    config = filter_config(args)
    problem = polish_estimate(result, vehicle, run_, config.measurement_std, burn_in_s=POLISH_BURN_IN_S,
                              prior_log_std_floor=config.prior_log_std_floor, effects=effects)
    if problem:
        where = "" if problem.startswith(f"{run_.source}:") else f"{run_.source}: "
        print(f"online-id: warning: {where}{problem}", file=sys.stderr)
        return
    p = result.polish
    print(f"polished the {result.filter.upper()} estimate by a batch fit over the whole run: {p['iterations']}"
          f" evaluations, {p['wall_s']:.2f} s; covariance × {p['covariance_inflation']:.2f} for correlated residuals")


def estimate_source(args, estimator_for, vehicle, effects=()):
    """Run the filter over LOG, any source drivers/sources.py reads. The estimator is built for the channels
    used (--channels): a channel left out is not configured at all, whatever the source sends.
    Returns the result and the source's warnings."""
    from drivers.sources import only_channels, open_source, record_source, select_channels
    from online_id.estimation import run_estimator

    source = open_source(args.log, **source_options(args))
    channels = select_channels(args.channels, source)
    config = filter_config(args)
    if args.channels:
        config = replace(config, measurement_std={c: v for c, v in config.measurement_std.items() if c in channels})
    run_ = getattr(source, "run", None)  # a track run: its length and its truth are known
    polish = polish_wanted(args, whole_run=run_ is not None)
    samples = source if channels == source.channels else only_channels(source, channels)
    estimator = estimator_for(config, channels)  # a bad --effect is an error before any check
    if run_ is not None:
        check_run(run_, vehicle, args)
    else:  # a CAN or MDF log: its samples are held until judged
        samples = checked_stream(samples, vehicle, args, str(args.log), max_window_s=None)
    with source:
        result = run_estimator(estimator, samples, total=len(run_) if run_ is not None else None,
                               progress=not args.quiet and run_ is not None, source=source.name,
                               truth=run_truth(run_) if run_ is not None else None, channels=channels)
    warnings = record_source(result, source, channels)
    if polish and not result.interrupted:
        polish_result(result, vehicle, run_, args, effects)
    return result, warnings


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


def input_paths(args) -> dict:
    """The files a command reads, by flag, for :meth:`Outputs.check` (no output may overwrite one)."""
    from online_id.io.tracklog import truth_sidecar_path

    paths = {}
    for flag, attr in (("LOG", "log"), ("--prior", "prior"), ("--validate", "validate"), ("--dbc", "dbc"),
                       ("--signals", "signals"), ("--vehicle", "vehicle"),
                       ("--effects-from", "effects_from")):
        value = getattr(args, attr, None)
        if value is not None and Path(value).exists():
            paths[flag] = Path(value)
    if "LOG" in paths:
        paths["LOG's truth sidecar"] = truth_sidecar_path(paths["LOG"])
    return paths


def write_outputs(result, args, extra: dict | None = None):
    """Write --json (with ``extra`` keys), --trace and --plot, each atomically; returns the Outputs."""
    outputs = Outputs()
    if args.json is not None:
        data = dict(result.to_json_dict(), **(extra or {}))
        if library_warnings.counts():
            data["warning_counts"] = library_warnings.counts()
        outputs.write_text(args.json, json.dumps(data, indent=2) + "\n")
    outputs.write_with(args.trace, result.trace.write_csv)
    if getattr(args, "plot", None) is not None:
        from online_id.plots.convergence import plot_convergence

        outputs.write_with(args.plot, lambda tmp: plot_convergence(
            [(result.filter.upper(), result)], tmp, truth=result.truth,
            title=f"{result.filter.upper()} estimate over {result.source}"))
    return outputs
