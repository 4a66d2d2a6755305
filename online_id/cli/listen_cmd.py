"""``online-id listen``: live estimation from a CAN bus, with a refreshing table."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from online_id.cli import termination
from online_id.cli.bus_args import add_bus_arguments, add_dbc_arguments, bus_kwargs
from online_id.cli.common import add_filter_argument, add_intersample_argument, add_vehicle_argument, printed_messages
from online_id.cli.effect_args import add_effect_arguments, extra_state_lines
from online_id.cli.estimate_cmd import add_strict_argument, input_paths, strict_status, write_outputs
from online_id.cli.outputs import Outputs, StreamedOutput
from online_id.cli.plausibility_args import add_plausibility_argument
from online_id.errors import OnlineIdError
from online_id.trust.consistency import judge_estimator, verdict_line, verdict_lines
from online_id.vehicle.parameters import PARAMETER_NAMES
from online_id.workflows.listen_job import IDLE_TIMEOUT_S, LIVE_CHECK_WINDOW_S

#: Exit status when the bus gave nothing to estimate from (no frame before --start-timeout, or
#: frames of which none made a sample): the input, not the tool, is missing, as with a bad log.
EXIT_NOTHING_RECEIVED = 2


def add_parser(sub) -> None:
    p = sub.add_parser(
        "listen",
        description="Decode sensor frames from a bus (online-id's own frames by default, or a car's with"
        " --dbc and --signals), estimate online and show a refreshing table. Ctrl-C, the end of the stream"
        " (nothing for --idle-timeout s) or a lost bus end the run; the trace and the JSON are written"
        " either way. Lost frames and samples (COUNTER and SAMPLE_TIME gaps) are counted per signal, shown"
        " in the table and written to the JSON (lost_samples).",
    )
    add_bus_arguments(p)
    add_dbc_arguments(p)
    add_vehicle_argument(p)
    add_filter_argument(p)
    p.add_argument("--prior", type=Path, metavar="FIT.json", help="start from a fit's values and σ")
    p.add_argument("--correct-every", type=int, metavar="K", help="correct every K-th sample (default: 20)")
    add_intersample_argument(p)
    p.add_argument("--idle-timeout", type=float, default=IDLE_TIMEOUT_S,
                   help="end when nothing arrives for this long after the first frame [s]"
                   f" (default: {IDLE_TIMEOUT_S:g})")
    p.add_argument("--start-timeout", type=float, default=None,
                   help="give up when no frame arrives within this many seconds, with exit status 2"
                   " (default: wait)")
    p.add_argument("--trace", type=Path, metavar="OUT.csv",
                   help="write the estimate's time history, as the run goes (into OUT.csv.partial, renamed to"
                   " OUT.csv when the run ends)")
    p.add_argument("--json", type=Path, metavar="OUT.json", help="write the result as JSON")
    p.add_argument("--refresh", type=float, default=1.0, help="table refresh period [s] (default: 1)")
    p.add_argument("--check-window", type=float, default=LIVE_CHECK_WINDOW_S, metavar="S",
                   help="the plausibility checks judge the first seconds of the stream, at most S seconds of"
                   f" data (default: {LIVE_CHECK_WINDOW_S:g})")
    p.add_argument("--web", metavar="[HOST:]PORT",
                   help="serve a live page of the estimate (parameters with ±σ over time, the verdict, samples lost"
                   " per signal, an excitation meter) at http://HOST:PORT/ (default host 127.0.0.1: this machine"
                   " only; 0.0.0.0 serves every network; port 0 picks a free one)")
    p.add_argument("--web-linger", type=float, default=WEB_LINGER_S, metavar="S",
                   help="with --web, keep serving the final page this long after the run ends (Ctrl-C ends it"
                   f" sooner; default: {WEB_LINGER_S:g})")
    add_effect_arguments(p)
    add_plausibility_argument(p)
    add_strict_argument(p)
    p.set_defaults(run=run, plot=None)


#: Seconds the live page stays up after the run, so an open tab shows the final numbers (``--web-linger``).
WEB_LINGER_S = 5.0


#: Characters of the live verdict line shown in the table (the full reasons go to the final line and JSON).
VERDICT_WIDTH = 160


class _LiveTable:
    """Redraws the estimate in place on a terminal, or prints a line every few seconds otherwise."""

    def __init__(self, period: float, stream=None):
        # (sys.stdout when the table is made, not when this module was imported: that one may be closed since)
        self.period, self.stream = period, stream if stream is not None else sys.stdout
        self.stats = None  # online_id.drivers.assembler.FrameStats: loss per signal
        self.tty = self.stream.isatty()
        self.next = 0.0
        self.lines = 0

    def __call__(self, est, sample, stats=None) -> None:
        self.stats = stats
        now = time.monotonic()
        if now < self.next:
            return
        self.next = now + (self.period if self.tty else max(self.period, 5.0))
        vals, sds = est.parameters.to_vector(), est.parameter_std
        rows = [f"t = {sample.time:9.2f} s  V = {sample.speed * 3.6:6.1f} km/h  samples {est.events['samples']}"]
        rows += [f"  {n:<4} {v:>12.6g} ± {s:<10.3g}" for n, v, s in zip(PARAMETER_NAMES, vals, sds)]
        extra = extra_state_lines(est.extra_states)  # offsets and effect parameters (--offsets, --effect)
        rows += [f"  {line}" for line in extra]
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
                              + "".join(f"  [{line}]" for line in extra)
                              + (f"  {loss}" if loss else "") + "  " + rows[-1] + "\n")
        self.stream.flush()

    def _loss(self) -> str:
        st = self.stats
        if st is None or not (st.lost_samples or st.stale or st.counter_mismatch):
            return ""
        per_signal = ", ".join(f"{k} {v}" for k, v in st.lost_by_signal.items() if v)
        return f"  lost: {st.lost_samples} samples ({100 * st.loss_fraction():.1f} %); by signal: {per_signal}"


def run(args: argparse.Namespace) -> int:
    Outputs.check({"--json": args.json, "--trace": args.trace}, input_paths(args))
    on_sample, view = _LiveTable(args.refresh), None
    if args.web is not None:
        from online_id.report.live import LiveView, parse_address

        view = LiveView(f"{args.interface}:{args.channel}", *parse_address(args.web))
        print(f"live page: {view.start()}", flush=True)
        on_sample = _both(on_sample, view)
    trace = None if args.trace is None else StreamedOutput("--trace", args.trace)  # written as the run goes
    try:
        return _listen(args, on_sample, view, trace)
    except OnlineIdError:  # the run ended before any result (the bus, a failed check): no trace, as no JSON
        if trace is not None:
            trace.discard()
        raise
    finally:
        if trace is not None and not trace.done:  # an internal error mid-run: the rows so far are kept
            trace.finish(Outputs())
        if view is not None:
            view.close()


def _both(table, view):
    def on_sample(est, sample, stats=None):
        table(est, sample, stats)
        view(est, sample, stats)

    return on_sample


def _listen(args, on_sample, view, trace: StreamedOutput | None) -> int:
    from online_id.workflows import listen

    live = listen(args.interface, args.channel, bus_kwargs=bus_kwargs(args), dbc=args.dbc, signals=args.signals,
                  vehicle=args.vehicle, filter=args.filter, prior=args.prior, correct_every=args.correct_every,
                  intersample=args.intersample,
                  effects=args.effect, effects_from=args.effects_from, offsets=args.offsets,
                  idle_timeout=args.idle_timeout, start_timeout=args.start_timeout, check_window=args.check_window,
                  allow_implausible=args.allow_implausible, on_sample=on_sample, messages=printed_messages(),
                  trace=None if trace is None else trace.file)
    result, name = live.result, live.name
    print(f"{result.samples} samples from {name}; ended by {live.ended_by}")
    print(result.table())
    print(result.events_summary())
    for line in extra_state_lines(result.extra_states):
        print(line)
    print("\n".join(verdict_lines(result.consistency, getattr(args, "argv", None), "LOG")))
    outputs = write_outputs(result, args, extra=live.loss, trace=trace)  # after the results are printed
    if view is not None:
        view.finish(live)
        _linger(args.web_linger)
    if result.interrupted:
        return outputs.status(termination.exit_status())
    if live.nothing_arrived:
        from online_id.drivers.can_bus import in_process_only

        why = in_process_only(args.interface)
        print(f"online-id: error: {name}: no frame arrived within --start-timeout {args.start_timeout:g} s"
              + (f" ({why})" if why else ""), file=sys.stderr)
        return outputs.status(EXIT_NOTHING_RECEIVED)
    if live.frames and not live.samples_made:
        print(f"online-id: error: {name}: {live.frames} frame(s) received, none made a sample", file=sys.stderr)
        return outputs.status(EXIT_NOTHING_RECEIVED)
    if (live.ended_by or "").startswith("bus lost"):
        return outputs.status(1)
    return outputs.status(strict_status(result.consistency, args))


def _linger(seconds: float) -> None:
    """Keep the final page served for ``seconds`` (Ctrl-C ends the wait, not the command's status)."""
    if seconds <= 0:
        return
    print(f"the live page shows the final numbers for {seconds:g} s (Ctrl-C to end now)", flush=True)
    try:
        time.sleep(seconds)
    except KeyboardInterrupt:
        pass
