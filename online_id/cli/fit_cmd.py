"""``online-id fit``: Haro's hybrid-GA batch fit of the 8 parameters to a track-run log."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from online_id.batchfit.ga import GAConfig
from online_id.cli import library_warnings, termination
from online_id.cli.common import add_intersample_argument, log_parent, printed_messages, source_options
from online_id.cli.effect_args import add_effect_arguments, extra_state_lines
from online_id.cli.estimate_cmd import add_strict_argument, input_paths, strict_status
from online_id.cli.outputs import Outputs, json_text
from online_id.cli.plausibility_args import add_plausibility_argument
from online_id.cli.prior_args import add_prior_arguments
from online_id.trust.consistency import verdict_lines
from online_id.util import stages


def add_parser(sub) -> None:
    p = sub.add_parser(
        "fit",
        parents=[log_parent()],
        description="Fit the 8 parameters to a whole track run by minimising Haro's cost (eq 12) with the"
        " hybrid genetic algorithm, polish each minimum found, choose the one consistent with the prior,"
        " and estimate the covariance from the cost curvature. Its --json is a prior for"
        " 'online-id estimate --prior'. With no LOG, the built-in run is used.",
    )
    add_prior_arguments(p, keep_std=False)
    p.add_argument("--generations", type=int, default=GAConfig.generations,
                   help=f"GA generations (default: {GAConfig.generations}; stops earlier when it stalls)")
    p.add_argument("--groups", type=int, default=GAConfig.groups,
                   help=f"GA groups of 9 individuals (default: {GAConfig.groups})")
    p.add_argument("--bounds", type=float, nargs=2, default=(0.2, 5.0), metavar=("LOW", "HIGH"),
                   help="search bounds as factors of the prior (default: 0.2 5)")
    p.add_argument("--seed", type=int, default=0, help="GA seed (default: 0)")
    add_effect_arguments(p, offsets=False)
    add_intersample_argument(p)
    p.add_argument("--json", type=Path, metavar="OUT.json", help="write the result as JSON")
    p.add_argument("--plot", type=Path, metavar="OUT.png", help="measured vs simulated and residuals (Haro Figs 9-11)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    add_plausibility_argument(p)
    add_strict_argument(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from online_id.workflows import fit

    Outputs.check({"--json": args.json, "--plot": args.plot}, input_paths(args))
    done = fit(args.log, vehicle=args.vehicle, generations=args.generations, groups=args.groups,
               bounds=tuple(args.bounds), seed=args.seed, fixed=args.fix, effects=args.effect,
               effects_from=args.effects_from, allow_implausible=args.allow_implausible, resample=args.resample,
               intersample=args.intersample, progress=not args.quiet, messages=printed_messages(),
               **source_options(args))
    result = done.result
    stages.keep("the fit", lambda failure: write_fit_json(done, args, Outputs(), failure.to_json_dict()))
    print(f"batch fit over {result.run.source}: {result.evaluations} cost evaluations, {result.ga.generations}"
          f" generations, {result.wall_s:.1f} s; channels: {', '.join(result.channels)}")
    print(result.table())
    print(f"cost (eq 12): {result.cost:.5g}; RMS errors: "
          + ", ".join(f"{c} {v:.4g}" for c, v in result.rms_errors.items()))
    print(f"minima found: {len(result.minima)}; {result.choice_reason}")
    for line in extra_state_lines({"effects": result.effects}):
        print(line)
    if done.handling is not None:
        print("\n".join(done.handling.lines(of="the fit")))
    print("\n".join(verdict_lines(result.consistency, getattr(args, "argv", None), args.log)))
    for note in result.warnings:
        if not library_warnings.was_shown(note):
            print(f"online-id: warning: {note}", file=sys.stderr)
    outputs = write_fit_json(done, args, Outputs())  # after the results are printed: a failed write loses nothing
    if args.plot is not None:
        from online_id.plots.fit import plot_fit

        outputs.write_with(args.plot, lambda tmp: plot_fit(result, tmp))
    if result.interrupted:
        print(f"interrupted ({termination.signal_name()}): the results above are the best reached so far",
              file=sys.stderr)
        return outputs.status(termination.exit_status())
    return outputs.status(strict_status(result.consistency, args))


def write_fit_json(done, args, outputs: Outputs, failure: dict | None = None) -> Outputs:
    """--json of a fit (the workflow's :class:`~online_id.workflows.results.Fit`; ``failure``: the stage that
    failed after it, see online_id/util/stages.py)."""
    if args.json is not None:
        data = done.to_json_dict()
        if library_warnings.counts():
            data["warning_counts"] = library_warnings.counts()
        if failure is not None:
            data["failure"] = failure
        outputs.write_text(args.json, json_text(data))
    return outputs
