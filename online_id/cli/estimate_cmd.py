"""``online-id estimate``: run the online filter over a track-run log (or the built-in run)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from online_id.cli import library_warnings, termination
from online_id.cli.common import (
    LOG_HELP,
    add_filter_arguments,
    add_resample_argument,
    add_source_arguments,
    add_vehicle_argument,
    print_deferred,
    printed_messages,
    source_options,
)
from online_id.cli.effect_args import add_effect_arguments, extra_state_lines
from online_id.cli.outputs import Outputs, json_text
from online_id.cli.plausibility_args import add_plausibility_argument
from online_id.cli.prior_args import add_prior_arguments
from online_id.trust.consistency import verdict_lines
from online_id.util import stages


def add_parser(sub) -> None:
    p = sub.add_parser(
        "estimate",
        description="Run the augmented-state EKF or UKF over a track-run CSV, sample by sample, and print"
        " prior, estimate, 1σ (and truth for simulated runs). With no LOG, a built-in simulated run is used."
        " A CAN log (candump .log, .asc, .blf, .trc, .mf4, ...) is decoded with --dbc and --signals (default:"
        " online-id's own frames); an MDF file of decoded signals is read by column name or by --signals.",
    )
    p.add_argument("log", nargs="?", type=Path, metavar="LOG", help=LOG_HELP)
    add_vehicle_argument(p)
    add_estimate_flags(p)
    p.add_argument("--json", type=Path, metavar="OUT.json", help="write the result as JSON")
    p.add_argument("--trace", type=Path, metavar="OUT.csv", help="write the estimate's time history as CSV")
    p.add_argument("--plot", type=Path, metavar="OUT.png", help="draw the convergence of each parameter")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    add_strict_argument(p)
    p.set_defaults(run=run)


def add_estimate_flags(p) -> None:
    """The flags of the estimate workflow (:func:`estimate_options` reads them): ``estimate`` and ``batch``
    take the same, so a flag added here reaches both."""
    add_filter_arguments(p)
    add_source_arguments(p)
    add_resample_argument(p)
    add_prior_arguments(p)
    add_plausibility_argument(p)
    add_effect_arguments(p)
    p.add_argument("--polish", action=argparse.BooleanOptionalAction, default=None,
                   help="after the filter, polish its estimate by a batch output-error fit over the whole log"
                   " (Gauss-Newton, reaches the Cramér-Rao bound; the filter's own estimate goes to 'online' in"
                   " --json; parameters held by --fix stay held). Default: on for every log (any format) and the"
                   " built-in run; off with --offsets")


def add_strict_argument(p) -> None:
    p.add_argument("--strict", action="store_true",
                   help="exit 3 when the run is judged inconsistent with the model (after writing the outputs);"
                   " a run too short to judge exits 0 with a note")


def strict_status(consistency: dict | None, args) -> int:
    """3 under --strict when the verdict is inconsistent, else 0 (a verdict that could not be judged is 0,
    with a note that --strict did not judge it)."""
    if not getattr(args, "strict", False) or consistency is None:
        return 0
    if consistency["consistent"] is None:
        print("online-id: note: --strict: the run could not be judged (see the verdict line); exit status 0"
              " says only that no check failed", file=sys.stderr)
        return 0
    return 0 if consistency["consistent"] else 3


def run(args: argparse.Namespace) -> int:
    from online_id.workflows import estimate

    Outputs.check({"--json": args.json, "--trace": args.trace, "--plot": args.plot}, input_paths(args))
    est = estimate(args.log, progress=not args.quiet, messages=printed_messages(defer=("note",)),
                   **estimate_options(args))
    result = est.result
    stages.keep("the filter's estimate",  # should anything below fail unexpectedly
                lambda failure: write_outputs(result, args, extra={"failure": failure.to_json_dict()}))
    split = "" if result.wall_s_filter is None else f" (filter {result.wall_s_filter:.2f} s, polish" \
        f" {result.wall_s - result.wall_s_filter:.2f} s)"
    print(f"{result.filter.upper()} over {est.label}: {result.samples} samples in {result.wall_s:.2f} s{split}"
          f" ({result.sim_seconds / max(result.wall_s, 1e-9):.1f}x real time); channels: {', '.join(result.channels)}")
    print(result.table())
    print(result.events_summary())
    for line in extra_state_lines(result.extra_states):
        print(line)
    if result.cross_check:
        print(f"cross-check against {args.prior} (difference in combined σ; |z| > 3 disagrees):")
        for n, c in result.cross_check.items():
            if not c.get("compared", True):
                print(f"  {n:<4} filter {c['estimate']:.6g}  fit {c['fit']:.6g}  not compared:"
                      f" {c['not_compared_because']}")
                continue
            flag = "  DISAGREES" if c["disagree"] else ""
            print(f"  {n:<4} filter {c['estimate']:.6g}  fit {c['fit']:.6g}  z {c['z']:+.2f}{flag}")
    missing = [n for n, ok in result.informed.items() if not ok and n not in result.fixed]
    if missing:
        print(f"not informed by this run (σ above half its prior σ): {', '.join(missing)}")
    if result.handling is not None:
        print("\n".join(result.handling.lines()))
    print("\n".join(verdict_lines(result.consistency, getattr(args, "argv", None), args.log)))
    print_deferred(est.messages)
    outputs = write_outputs(result, args)  # after the results are printed: a failed write loses nothing
    if result.interrupted:
        print(f"interrupted ({termination.signal_name()}): the results above are those reached so far", file=sys.stderr)
        return outputs.status(termination.exit_status())
    return outputs.status(strict_status(result.consistency, args))


def estimate_options(args) -> dict:
    """The estimate workflow's keywords from the flags ``estimate`` (and ``batch``, which takes the same)
    parse: plain values (paths as strings), so they travel to batch workers and into its JSON."""
    def path(p):
        return None if p is None else str(p)

    return {"vehicle": args.vehicle, "filter": args.filter, "prior": path(args.prior), "channels": args.channels,
            "correct_every": args.correct_every, "keep_prior_std": args.keep_prior_std, "fixed": list(args.fix),
            "effects": list(args.effect), "effects_from": path(args.effects_from), "offsets": args.offsets,
            "polish": args.polish, "allow_implausible": args.allow_implausible, "resample": args.resample,
            "intersample": args.intersample,
            **source_options(args)}


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


def write_outputs(result, args, extra: dict | None = None, trace=None):
    """Write --json (with ``extra`` keys), --trace and --plot, each atomically; returns the Outputs. ``trace``:
    the --trace written as the run went (a :class:`~online_id.cli.outputs.StreamedOutput`), put in place."""
    outputs = Outputs()
    if args.json is not None:
        data = dict(result.to_json_dict(), **(extra or {}))
        if library_warnings.counts():
            data["warning_counts"] = library_warnings.counts()
        outputs.write_text(args.json, json_text(data))
    if trace is not None:
        trace.finish(outputs)
    else:
        outputs.write_with(args.trace, result.trace.write_csv)
    if getattr(args, "plot", None) is not None:
        from online_id.plots.convergence import plot_convergence

        outputs.write_with(args.plot, lambda tmp: plot_convergence(
            [(result.filter.upper(), result)], tmp, truth=result.truth,
            title=f"{result.filter.upper()} estimate over {result.source}"))
    return outputs
