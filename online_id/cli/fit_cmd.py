"""``online-id fit``: Haro's hybrid-GA batch fit of the 8 parameters to a track-run log."""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

from online_id.cli.common import add_vehicle_argument, load_run, run_truth, vehicle_of
from online_id.cli.effect_args import add_effect_arguments, effects_of, extra_state_lines
from online_id.errors import OnlineIdError
from online_id.fit.ga import GAConfig


def add_parser(sub) -> None:
    p = sub.add_parser(
        "fit",
        help="batch fit of the 8 parameters (hybrid GA with Simplex recombination, Haro 2008)",
        description="Fit the 8 parameters to a whole track run by minimising Haro's cost (eq 12) with the"
        " hybrid genetic algorithm, polish each minimum found, choose the one consistent with the prior,"
        " and estimate the covariance from the cost curvature. Its --json is a prior for"
        " 'online-id estimate --prior'. With no LOG, the built-in run is used.",
    )
    p.add_argument("log", nargs="?", type=Path, metavar="LOG", help="track-run CSV (default: built-in run)")
    add_vehicle_argument(p)
    p.add_argument("--generations", type=int, default=GAConfig.generations,
                   help=f"GA generations (default: {GAConfig.generations}; stops earlier when it stalls)")
    p.add_argument("--groups", type=int, default=GAConfig.groups,
                   help=f"GA groups of 9 individuals (default: {GAConfig.groups})")
    p.add_argument("--bounds", type=float, nargs=2, default=(0.2, 5.0), metavar=("LOW", "HIGH"),
                   help="search bounds as factors of the prior (default: 0.2 5)")
    p.add_argument("--seed", type=int, default=0, help="GA seed (default: 0)")
    add_effect_arguments(p, offsets=False)
    p.add_argument("--json", type=Path, metavar="OUT.json", help="write the result as JSON")
    p.add_argument("--plot", type=Path, metavar="OUT.png", help="measured vs simulated and residuals (Haro Figs 9-11)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from online_id.fit.fit import FitConfig, fit_run

    vehicle = vehicle_of(args)
    for out in (args.json, args.plot):
        if out is not None and not out.parent.exists():
            raise OnlineIdError(f"{out}: folder {out.parent} does not exist")
    if args.generations < 1 or args.groups < 1:
        raise OnlineIdError("--generations and --groups must be at least 1")
    low, high = args.bounds
    if not 0 < low < 1 < high:
        raise OnlineIdError(f"--bounds must satisfy 0 < LOW < 1 < HIGH, got {low:g} {high:g}")
    effects = effects_of(args)
    run_ = load_run(args.log, vehicle)
    config = FitConfig(lower_factor=low, upper_factor=high,
                       ga=replace(GAConfig(), generations=args.generations, groups=args.groups))
    result = fit_run(vehicle, run_, config, seed=args.seed, truth=run_truth(run_), progress=not args.quiet,
                     effects=effects)
    print(f"batch fit over {run_.source}: {result.evaluations} cost evaluations, {result.ga.generations}"
          f" generations, {result.wall_s:.1f} s; channels: {', '.join(result.channels)}")
    print(result.table())
    print(f"cost (eq 12): {result.cost:.5g}; RMS errors: "
          + ", ".join(f"{c} {v:.4g}" for c, v in result.rms_errors.items()))
    print(f"minima found: {len(result.minima)}; {result.choice_reason}")
    for line in extra_state_lines({"effects": result.effects}):
        print(line)
    for note in result.warnings:
        print(f"online-id: warning: {note}", file=sys.stderr)
    if args.json is not None:
        result.write_json(args.json)
        print(f"wrote {args.json}")
    if args.plot is not None:
        from online_id.plots.fit import plot_fit

        plot_fit(result, args.plot)
        print(f"wrote {args.plot}")
    return 0
