"""``online-id report``: one self-contained HTML page of a run (check, estimate, fit, diagnosis)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from online_id.cli import termination
from online_id.cli.common import (
    add_filter_argument,
    add_intersample_argument,
    log_parent,
    printed_messages,
    source_options,
)
from online_id.cli.estimate_cmd import input_paths
from online_id.cli.outputs import Outputs
from online_id.cli.plausibility_args import add_plausibility_argument


def add_parser(sub) -> None:
    p = sub.add_parser(
        "report",
        parents=[log_parent()],
        description="Run check, estimate, fit and diagnose over LOG (the built-in run without LOG), as their own"
        " commands do, and write one self-contained HTML page that opens offline: the run's channels, speed and"
        " |a_y|, what check says, the estimate with its verdict, trajectories with ±σ bands and innovations, an"
        " excitation meter (which stretches inform which parameter), the fit's agreement with the estimate, the"
        " diagnosis, and the command line of each part. The fit and the diagnosis take minutes on a long log:"
        " --no-fit, --no-diagnose leave them out.",
    )
    p.add_argument("--out", type=Path, required=True, metavar="RUN.html", help="the page to write")
    add_filter_argument(p)
    add_intersample_argument(p)
    p.add_argument("--fit", action=argparse.BooleanOptionalAction, default=True,
                   help="run the batch fit and compare it with the estimate (default: on)")
    p.add_argument("--diagnose", action=argparse.BooleanOptionalAction, default=True,
                   help="run the gap diagnosis (default: on)")
    p.add_argument("--generations", type=int, metavar="N", help="GA generations of the fit (default: the fit's)")
    p.add_argument("--effects", help="the diagnosis's candidates, comma-separated (default: all)")
    p.add_argument("--json", type=Path, metavar="OUT.json",
                   help="also write every part's JSON (as each command's --json) in one file")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    add_plausibility_argument(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from online_id.report.run_page import render
    from online_id.workflows import report

    Outputs.check({"--out": args.out, "--json": args.json}, input_paths(args))
    if args.generations is not None and args.generations < 1:
        from online_id.errors import OnlineIdError

        raise OnlineIdError("--generations must be at least 1")
    messages = printed_messages()
    if args.quiet:
        messages.echo = lambda kind, line: kind in ("warning", "result") and print(
            line if kind == "result" else f"online-id: warning: {line}",
            file=sys.stdout if kind == "result" else sys.stderr)
    rep = report(args.log, vehicle=args.vehicle, filter=args.filter, fit=args.fit, diagnose=args.diagnose,
                 generations=args.generations, effects=args.effects, allow_implausible=args.allow_implausible,
                 resample=args.resample, intersample=args.intersample, progress=not args.quiet, out=args.out,
                 messages=messages,
                 **source_options(args))
    from online_id.trust.consistency import verdict_line

    print(verdict_line(rep.estimate.result.consistency))
    outputs = Outputs()
    outputs.write_text(args.out, render(rep))
    if args.json is not None:
        outputs.write_text(args.json, rep.to_json())
    if rep.interrupted:
        print(f"interrupted ({termination.signal_name()}) during {rep.interrupted}: the page holds the parts made",
              file=sys.stderr)
        return outputs.status(termination.exit_status())
    return outputs.status(0)
