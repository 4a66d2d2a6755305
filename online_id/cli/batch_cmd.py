"""``online-id batch``: estimate (and optionally fit and diagnose) many logs at once on Dask."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from online_id.cli.common import add_vehicle_argument
from online_id.cli.estimate_cmd import add_estimate_flags, estimate_options
from online_id.cli.outputs import Outputs
from online_id.errors import OnlineIdError


def add_parser(sub) -> None:
    p = sub.add_parser(
        "batch",
        description="Run the online estimator (and with --fit / --diagnose the batch fit and the gap"
        " diagnosis) over every LOG on a dask.distributed cluster: a local one with --workers processes by"
        " default, or an existing one with --scheduler. Writes DIR/summary.csv (one row per log: log, status"
        " ok/failed, error, samples, each parameter's value and 1σ in SI units, the consistency verdict) and"
        " DIR/<log>.<hash>.json, and DIR/index.html (the logs' estimates side by side in a browser). A log that"
        " fails is a failed row, never the end of the batch; logs already"
        " done (same file, same options) are skipped when the batch is run again. Exit status 1 when any"
        " log failed.",
    )
    p.add_argument("logs", nargs="+", type=Path, metavar="LOG", help="track-run CSVs or CAN logs (with --dbc)")
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="output folder (created if missing)")
    p.add_argument("--workers", type=int, default=2,
                   help="worker processes of the local cluster, one thread each (default: 2; 0 runs inline)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="use an existing Dask cluster, e.g. tcp://10.0.0.5:8786, instead of a local one")
    add_vehicle_argument(p)
    add_estimate_flags(p)  # every flag of 'online-id estimate' that is not about one log's outputs
    p.add_argument("--fit", action="store_true", help="also run the batch fit of each log")
    p.add_argument("--diagnose", action="store_true", help="also run the gap diagnosis of each log")
    p.add_argument("--generations", type=int, metavar="N", help="GA generations of --fit (default: the fit's)")
    p.add_argument("--force", action="store_true", help="run every log again, even those already done")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from online_id.batch import BatchOptions, run_batch
    from online_id.workflows.inputs import effects_of, filter_effects_of, vehicle_of

    if args.workers < 0:
        raise OnlineIdError("--workers must be 0 or more")
    if args.out.exists() and not args.out.is_dir():
        raise OnlineIdError(f"--out {args.out}: not a folder")
    Outputs.check_writable("--out", args.out, folder=True)  # before any worker starts
    if args.generations is not None and args.generations < 1:
        raise OnlineIdError("--generations must be at least 1")
    seen: set[Path] = set()
    logs = []
    for p in args.logs:
        if p.resolve() not in seen:
            seen.add(p.resolve())
            logs.append(p)
    vehicle = vehicle_of(args.vehicle)
    online = filter_effects_of(args.effect, args.effects_from, vehicle.known)  # one error now, not one per log
    every = effects_of(args.effect, args.effects_from, online=False) if args.fit else []
    rest = {k: v for k, v in estimate_options(args).items()
            if k not in ("vehicle", "filter", "effects", "effects_from", "offsets", "dbc", "signals")}
    options = BatchOptions(vehicle=args.vehicle, filter=args.filter, fit=args.fit, diagnose=args.diagnose,
                           dbc=args.dbc, signals=args.signals, fit_generations=args.generations,
                           effects=tuple(e.estimate_spec() for e in online),
                           fit_effects=tuple(e.estimate_spec() for e in every), offsets=args.offsets,
                           estimate={k: v for k, v in rest.items() if v not in (None, False, [])})

    def progress(done: int, total: int, row: dict) -> None:
        if args.quiet:
            return
        what = "done earlier" if row["reused"] == "yes" else row["status"]
        print(f"[{done}/{total}] {what:<12} {_describe(row)}", file=sys.stderr, flush=True)

    where = args.scheduler or (f"a local cluster of {args.workers} worker(s)" if args.workers else "this process")
    if not args.quiet:
        print(f"{len(logs)} log(s) on {where}", file=sys.stderr, flush=True)
    result = run_batch(logs, args.out, options, workers=args.workers, scheduler=args.scheduler,
                       force=args.force, progress=progress)
    ok = len(result.rows) - len(result.failed)
    print(f"batch: {ok} ok, {len(result.failed)} failed, {result.reused} reused from an earlier run,"
          f" in {result.wall_s:.1f} s; wrote {result.summary_path}"
          + (f" and {result.index_path}" if result.index_path else ""))
    for row in result.failed:
        print(f"  failed: {_describe(row)}")
    if result.interrupted:
        from online_id.cli import termination

        print(f"interrupted ({termination.signal_name()}): the summary holds the logs that finished", file=sys.stderr)
        return termination.exit_status()
    return 1 if result.failed else 0


def _describe(row: dict) -> str:
    """The log and, for a failure, its error (which usually names the file already)."""
    if row["status"] == "ok":
        return f"{row['log']} ({row['samples']} samples)"
    err = row["error"]
    return err if err.startswith(row["log"]) else f"{row['log']}: {err}"
