"""``online-id replay``: play a track-run CSV or a CAN log onto a CAN bus at real-time rate."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from online_id.cli import termination
from online_id.cli.bus_args import add_bus_arguments, open_bus_from_args
from online_id.cli.outputs import Outputs
from online_id.errors import OnlineIdError


def add_parser(sub) -> None:
    p = sub.add_parser(
        "replay",
        description="Play LOG onto a bus at real-time rate × --speed. A track-run CSV is sent as online-id's"
        " own frames (drivers/data/online_id.dbc, 3-4 frames per sample); a CAN log (candump .log, .asc,"
        " .blf, ...) is sent frame by frame as recorded. At the end the timing error (p50, p99, max"
        " lateness) and the frame count are printed.",
    )
    p.add_argument("log", type=Path, metavar="LOG")
    add_bus_arguments(p)
    p.add_argument("--speed", type=float, default=1.0, help="playback speed factor (default: 1 = real time)")
    p.add_argument("--loop", action="store_true", help="start again at the end (Ctrl-C stops)")
    p.add_argument("--json", type=Path, metavar="OUT.json", help="write the timing report as JSON")
    p.add_argument("--no-priority", action="store_true",
                   help="do not try to raise the process priority (by default it is raised where permitted)")
    p.set_defaults(run=run)


def frame_factory(log: Path):
    """A callable giving the frames of LOG afresh (so --loop can restart)."""
    import can

    if not log.exists():
        raise OnlineIdError(f"{log}: no such file")
    if log.suffix.lower() == ".csv":
        from online_id.drivers.frames import frames_from_run, load_own_dbc
        from online_id.io.tracklog import read_track_run

        run = read_track_run(log)
        db = load_own_dbc()
        return (lambda: frames_from_run(run, db)), len(run) * (4 if run.roll_angle is not None else 3)
    try:
        frames = list(can.LogReader(str(log)))
    except Exception as exc:  # python-can raises per-format errors
        raise OnlineIdError(f"{log}: not a CAN log python-can can read: {exc}") from None
    return (lambda: iter(frames)), len(frames)


def run(args: argparse.Namespace) -> int:
    import json

    from online_id.replay.player import play, raise_priority

    if args.speed <= 0:
        raise OnlineIdError("--speed must be positive")
    Outputs.check({"--json": args.json}, {"LOG": args.log})
    frames, count = frame_factory(args.log)
    bus = open_bus_from_args(args)
    from online_id.drivers.can_bus import in_process_only

    if in_process_only(args.interface):
        print(f"online-id: warning: {args.interface}:{args.channel}: {in_process_only(args.interface)}",
              file=sys.stderr, flush=True)
    print(f"replaying {args.log} ({count} frames) onto {args.interface}:{args.channel} at {args.speed:g}x"
          f"{' in a loop' if args.loop else ''}", flush=True)
    priority = "normal (--no-priority)" if args.no_priority else raise_priority()
    try:
        report = play(frames, bus, speed=args.speed, loop=args.loop)
    finally:
        bus.shutdown()
    print(report.summary(), flush=True)
    print(f"process priority: {priority}", flush=True)
    outputs = Outputs()
    if args.json is not None:
        outputs.write_text(args.json, json.dumps(dict(report.to_dict(), priority=priority), indent=2) + "\n")
    if report.ended_by == "interrupted":
        return outputs.status(termination.exit_status())
    return outputs.status(1 if report.ended_by.startswith("bus lost") else 0)



