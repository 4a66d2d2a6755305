"""``online-id listen``: live estimation from a CAN bus, with a refreshing table."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from online_id.cli import signals
from online_id.cli.bus_args import add_bus_arguments, add_dbc_arguments, dbc_and_map, open_bus_from_args
from online_id.cli.common import add_vehicle_argument, read_prior, vehicle_of
from online_id.cli.effect_args import add_effect_arguments, extra_state_lines, filter_effects_of, offsets_of
from online_id.cli.estimate_cmd import (
    add_strict_argument,
    filter_config,
    input_paths,
    strict_status,
    write_outputs,
)
from online_id.cli.outputs import Outputs
from online_id.cli.plausibility_args import add_plausibility_argument, checked_stream
from online_id.errors import OnlineIdError
from online_id.trust.consistency import judge_estimator, verdict_line
from online_id.vehicle.parameters import PARAMETER_NAMES

#: Exit status when the bus gave nothing to estimate from (no frame before --start-timeout, or
#: frames of which none made a sample): the input, not the tool, is missing, as with a bad log.
EXIT_NOTHING_RECEIVED = 2

#: The plausibility checks judge a live stream within its first 30 s (sooner once it has turned enough).
LIVE_CHECK_WINDOW_S = 30.0


def add_parser(sub) -> None:
    p = sub.add_parser(
        "listen",
        help="estimate the parameters live from a CAN bus",
        description="Decode sensor frames from a bus (online-id's own frames by default, or a car's with"
        " --dbc and --signals), estimate online and show a refreshing table. Ctrl-C, the end of the stream"
        " (nothing for --idle-timeout s) or a lost bus end the run; the trace and the JSON are written"
        " either way. Lost frames and samples (COUNTER and SAMPLE_TIME gaps) are counted per signal, shown"
        " in the table and written to the JSON (lost_samples).",
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
                   help="give up when no frame arrives within this many seconds, with exit status 2"
                   " (default: wait)")
    p.add_argument("--trace", type=Path, metavar="OUT.csv", help="write the estimate's time history")
    p.add_argument("--json", type=Path, metavar="OUT.json", help="write the result as JSON")
    p.add_argument("--refresh", type=float, default=1.0, help="table refresh period [s] (default: 1)")
    p.add_argument("--check-window", type=float, default=LIVE_CHECK_WINDOW_S, metavar="S",
                   help="the plausibility checks judge the first seconds of the stream, at most S seconds of"
                   f" data (default: {LIVE_CHECK_WINDOW_S:g})")
    add_effect_arguments(p)
    add_plausibility_argument(p)
    add_strict_argument(p)
    p.set_defaults(run=run, plot=None)


#: Characters of the live verdict line shown in the table (the full reasons go to the final line and JSON).
VERDICT_WIDTH = 160


class _LiveTable:
    """Redraws the estimate in place on a terminal, or prints a line every few seconds otherwise."""

    def __init__(self, period: float, stream=sys.stdout, stats=None):
        self.period, self.stream = period, stream
        self.stats = stats  # drivers.assembler.FrameStats: loss per signal
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
        loss = self._loss()
        if loss:
            rows.append(loss)
        verdict = verdict_line(judge_estimator(est))
        rows.append(verdict if len(verdict) <= VERDICT_WIDTH else verdict[:VERDICT_WIDTH - 1] + "…")
        if self.tty:
            if self.lines:
                self.stream.write(f"\x1b[{self.lines}F")
            self.stream.write("\n".join(r + "\x1b[K" for r in rows) + "\n")
            self.lines = len(rows)
        else:
            self.stream.write(rows[0] + "  " + "  ".join(f"{n}={v:.5g}" for n, v in zip(PARAMETER_NAMES, vals))
                              + (f"  {loss}" if loss else "") + "  " + rows[-1] + "\n")
        self.stream.flush()

    def _loss(self) -> str:
        st = self.stats
        if st is None or not (st.lost_samples or st.stale or st.counter_mismatch):
            return ""
        per_signal = ", ".join(f"{k} {v}" for k, v in st.lost_by_signal.items() if v)
        return f"  lost: {st.lost_samples} samples ({100 * st.loss_fraction():.1f} %); by signal: {per_signal}"


def run(args: argparse.Namespace) -> int:
    from drivers.can_bus import CanBusSource
    from online_id.estimation import make_estimator, run_estimator

    vehicle = vehicle_of(args)
    Outputs.check({"--json": args.json, "--trace": args.trace}, input_paths(args))
    prior, prior_rel = (None, None) if args.prior is None else read_prior(args.prior)
    effects = filter_effects_of(args, vehicle.known)  # a bad --effect is an error before the bus is opened
    db, smap = dbc_and_map(args)
    bus = open_bus_from_args(args)
    name = f"{args.interface}:{args.channel}"

    def problem(line):
        print(f"online-id: warning: {name}: {line}", file=sys.stderr, flush=True)

    source = CanBusSource(bus, db, smap, idle_timeout_s=args.idle_timeout, start_timeout_s=args.start_timeout,
                          name=name, on_problem=problem)
    estimator = make_estimator(vehicle, args.filter, prior=prior, prior_relative_std=prior_rel,
                               config=filter_config(args), effects=effects,
                               offsets=offsets_of(args, tuple(smap.signals)), channels=tuple(smap.signals))
    print(f"listening on {name} with {smap.name} frames, {args.filter.upper()} (Ctrl-C to stop)", flush=True)
    try:
        # live: estimate at once, judge alongside; a failed check ends the run before anything is reported
        samples = checked_stream(source, vehicle, args, name, max_window_s=args.check_window, hold=False)
        result = run_estimator(estimator, samples, source=name, channels=list(smap.signals),
                               on_sample=_LiveTable(args.refresh, stats=source.assembler.stats))
    finally:
        try:
            source.close()
        except OnlineIdError as exc:
            print(f"online-id: warning: {exc}", file=sys.stderr)
    if result.interrupted:
        source.ended_by = "interrupted"
    stats = source.assembler.stats
    result.source_report = {"ended_by": source.ended_by, "frames": source.report(), "bus": name,
                            "receive_buffer_bytes": source.receive_buffer_bytes}
    if source.lag_s:
        import numpy as np

        lag = np.array(source.lag_s)
        result.source_report["lag_s"] = {"p50": float(np.percentile(lag, 50)), "p99": float(np.percentile(lag, 99))}
    print(f"{result.samples} samples from {name}; ended by {source.ended_by}")
    print(result.table())
    print(result.events_summary())
    for line in extra_state_lines(result.extra_states):
        print(line)
    print(verdict_line(result.consistency))
    for line in source.problems():
        print(f"online-id: warning: {name}: {line}", file=sys.stderr)
    # loss at the top level of the JSON, beside the frame counts (details in source_report.frames)
    loss = {"lost_samples": stats.lost_samples, "lost_samples_fraction": round(stats.loss_fraction(), 6),
            "lost_by_signal": stats.lost_by_signal, "frames_received": stats.frames,
            "frames_lost": sum(stats.lost_frames.values()), "lost_frames_by_message": dict(stats.lost_frames)}
    outputs = write_outputs(result, args, extra=loss)  # after the results are printed
    if result.interrupted:
        return outputs.status(signals.exit_status())
    if source.nothing_arrived:
        print(f"online-id: error: {name}: no frame arrived within --start-timeout {args.start_timeout:g} s",
              file=sys.stderr)
        return outputs.status(EXIT_NOTHING_RECEIVED)
    if stats.frames and not stats.samples:
        print(f"online-id: error: {name}: {stats.frames} frame(s) received, none made a sample", file=sys.stderr)
        return outputs.status(EXIT_NOTHING_RECEIVED)
    if (source.ended_by or "").startswith("bus lost"):
        return outputs.status(1)
    return outputs.status(strict_status(result.consistency, args))
