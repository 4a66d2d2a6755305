"""``online-id listen``: live estimation from a CAN bus, with a refreshing table."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from online_id.cli.bus_args import add_bus_arguments, add_dbc_arguments, dbc_and_map, open_bus_from_args
from online_id.cli.common import add_vehicle_argument, read_prior, vehicle_of
from online_id.cli.estimate_cmd import add_strict_argument, filter_config, strict_status, write_outputs
from online_id.consistency import judge_estimator, verdict_line
from online_id.errors import OnlineIdError
from online_id.vehicle.parameters import PARAMETER_NAMES


def add_parser(sub) -> None:
    p = sub.add_parser(
        "listen",
        help="estimate the parameters live from a CAN bus",
        description="Decode sensor frames from a bus (online-id's own frames by default, or a car's with"
        " --dbc and --signals), estimate online and show a refreshing table. Ctrl-C, the end of the stream"
        " (nothing for --idle-timeout s) or a lost bus end the run; the trace and the JSON are written"
        " either way.",
    )
    add_bus_arguments(p)
    add_dbc_arguments(p)
    add_vehicle_argument(p)
    p.add_argument("--filter", choices=("ekf", "ukf"), default="ekf", help="online filter (default: ekf)")
    p.add_argument("--prior", type=Path, metavar="FIT.json", help="start from a fit's values and σ")
    p.add_argument("--correct-every", type=int, metavar="K", help="correct every K-th sample (default: 20)")
    p.add_argument("--idle-timeout", type=float, default=2.0,
                   help="end when nothing arrives for this long after the first frame [s] (default: 2)")
    p.add_argument("--start-timeout", type=float, default=None,
                   help="give up when no frame arrives within this many seconds (default: wait)")
    p.add_argument("--trace", type=Path, metavar="OUT.csv", help="write the estimate's time history")
    p.add_argument("--json", type=Path, metavar="OUT.json", help="write the result as JSON")
    p.add_argument("--refresh", type=float, default=1.0, help="table refresh period [s] (default: 1)")
    add_strict_argument(p)
    p.set_defaults(run=run, plot=None)


#: Characters of the live verdict line shown in the table (the full reasons go to the final line and JSON).
VERDICT_WIDTH = 160


class _LiveTable:
    """Redraws the estimate in place on a terminal, or prints a line every few seconds otherwise."""

    def __init__(self, period: float, stream=sys.stdout):
        self.period, self.stream = period, stream
        self.tty = stream.isatty()
        self.next = 0.0
        self.lines = 0

    def __call__(self, est, sample) -> None:
        now = time.monotonic()
        if now < self.next:
            return
        self.next = now + (self.period if self.tty else max(self.period, 5.0))
        vals, sds = est.parameters.to_vector(), est.parameter_std
        rows = [f"t = {sample.time:9.2f} s  V = {sample.speed * 3.6:6.1f} km/h  samples {est.events['samples']}"]
        rows += [f"  {n:<4} {v:>12.6g} ± {s:<10.3g}" for n, v, s in zip(PARAMETER_NAMES, vals, sds)]
        verdict = verdict_line(judge_estimator(est))
        rows.append(verdict if len(verdict) <= VERDICT_WIDTH else verdict[:VERDICT_WIDTH - 1] + "…")
        if self.tty:
            if self.lines:
                self.stream.write(f"\x1b[{self.lines}F")
            self.stream.write("\n".join(r + "\x1b[K" for r in rows) + "\n")
            self.lines = len(rows)
        else:
            self.stream.write(rows[0] + "  " + "  ".join(f"{n}={v:.5g}" for n, v in zip(PARAMETER_NAMES, vals))
                              + "  " + rows[-1] + "\n")
        self.stream.flush()


def run(args: argparse.Namespace) -> int:
    from drivers.can_bus import CanBusSource
    from online_id.estimation import make_estimator, run_estimator

    vehicle = vehicle_of(args)
    for out in (args.json, args.trace):
        if out is not None and not out.parent.exists():
            raise OnlineIdError(f"{out}: folder {out.parent} does not exist")
    prior, prior_rel = (None, None) if args.prior is None else read_prior(args.prior)
    db, smap = dbc_and_map(args)
    bus = open_bus_from_args(args)
    name = f"{args.interface}:{args.channel}"
    source = CanBusSource(bus, db, smap, idle_timeout_s=args.idle_timeout, start_timeout_s=args.start_timeout,
                          name=name)
    estimator = make_estimator(vehicle, args.filter, prior=prior, prior_relative_std=prior_rel,
                               config=filter_config(args))
    print(f"listening on {name} with {smap.name} frames, {args.filter.upper()} (Ctrl-C to stop)", flush=True)
    try:
        result = run_estimator(estimator, source, source=name, channels=list(smap.signals),
                               on_sample=_LiveTable(args.refresh))
    finally:
        try:
            source.close()
        except OnlineIdError as exc:
            print(f"online-id: warning: {exc}", file=sys.stderr)
    if result.interrupted:
        source.ended_by = "interrupted"
    result.source_report = {"ended_by": source.ended_by, "frames": source.report(), "bus": name}
    if source.lag_s:
        import numpy as np

        lag = np.array(source.lag_s)
        result.source_report["lag_s"] = {"p50": float(np.percentile(lag, 50)), "p99": float(np.percentile(lag, 99))}
    write_outputs(result, args)
    print(f"{result.samples} samples from {name}; ended by {source.ended_by}")
    print(result.table())
    print(result.events_summary())
    print(verdict_line(result.consistency))
    for line in source.problems():
        print(f"online-id: warning: {name}: {line}", file=sys.stderr)
    if result.interrupted:
        return 130
    return 1 if (source.ended_by or "").startswith("bus lost") else strict_status(result.consistency, args)
