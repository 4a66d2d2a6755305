"""The listen workflow: live estimation from a CAN bus (``online-id listen``), the plausibility checks
judging the first seconds beside it, and what the bus lost. The live table (or a browser view) is a
callback: the workflow never draws."""

from __future__ import annotations

from collections.abc import Callable

from online_id.errors import OnlineIdError
from online_id.trust.consistency import with_informed
from online_id.workflows.inputs import filter_config, filter_effects_of, offset_channels, prior_of, vehicle_of
from online_id.workflows.messages import Messages
from online_id.workflows.results import Listening

#: The plausibility checks judge a live stream within its first 30 s (sooner once it has turned enough).
LIVE_CHECK_WINDOW_S = 30.0
#: End when nothing arrives for this long after the first frame [s].
IDLE_TIMEOUT_S = 2.0
#: Rows of the estimate's history a live run keeps in memory (``result.trace``: evenly thinned over the whole
#: run, the last row exact); every row goes to ``trace``'s file as it comes (issue 40: hours in bounded memory).
LIVE_TRACE_ROWS = 10_000


def listen(interface: str, channel: str, *, bus_kwargs: dict | None = None, dbc=None, signals=None,
           vehicle=None, filter: str = "ekf", prior=None, correct_every: int | None = None, effects=(),
           effects_from=None, offsets: bool = False, idle_timeout: float = IDLE_TIMEOUT_S,
           start_timeout: float | None = None, check_window: float = LIVE_CHECK_WINDOW_S,
           allow_implausible: str | None = None, intersample: str | None = None, on_sample: Callable | None = None,
           messages: Messages | None = None, trace=None) -> Listening:
    """Estimate live from the bus ``interface``/``channel`` (python-can; ``bus_kwargs`` for ``can.Bus``) until
    Ctrl-C (or SIGTERM/SIGHUP), the end of the stream (nothing for ``idle_timeout`` s) or a lost bus.

    Parameters
    ----------
    interface, channel : the python-can bus (``udp_multicast`` and a group, ``socketcan`` and ``vcan0``, ...)
    bus_kwargs : more keywords for ``can.Bus`` (``--bus-arg``)
    dbc, signals : the car's frames (default: online-id's own); vehicle, filter, prior, correct_every,
        effects, effects_from, offsets, intersample : as in :func:`~online_id.workflows.estimate_job.estimate` (a
        live filter with the cubic works each sample when the next has come: one sample late)
    start_timeout : give up when no frame arrives within this many seconds (``nothing_arrived``)
    check_window : the plausibility checks judge at most this many seconds of the stream
    on_sample(estimator, sample, stats) : called after every sample (a live table, a browser view);
        ``stats`` is the frame assembler's :class:`online_id.drivers.assembler.FrameStats`
    idle_timeout : end when nothing arrives for this long after the first frame [s]
    allow_implausible : plausibility checks to accept (``--allow-implausible``)
    messages : where the run's lines go as they come
    trace : where the estimate's history goes as the run goes, in the trace CSV's format: a path (written and
        closed here) or an open text stream (written and flushed, left open); None: nowhere. Either way
        ``result.trace`` is an evenly thinned copy of at most :data:`LIVE_TRACE_ROWS` rows (and the last),
        so that memory does not grow with the run's length

    Notes
    -----
    The result keeps what was reached however the run ended; the verdict is ``result.consistency``.
    """
    import numpy as np

    from online_id.drivers.can_bus import CanBusSource, in_process_only, open_bus
    from online_id.drivers.sources import SourceOptions
    from online_id.estimation import make_estimator, run_estimator
    from online_id.tracing import StreamedTrace
    from online_id.trust.plausibility import StreamChecker, parse_allow

    messages = messages if messages is not None else Messages()
    car = vehicle_of(vehicle)
    prior_values, prior_rel = prior_of(prior)
    effect_list = filter_effects_of(effects, effects_from, car.known, messages)  # before the bus is opened
    smap, db = SourceOptions(dbc, signals).map_and_db()
    own_file = trace is not None and not hasattr(trace, "write")  # a path: opened here, before the bus
    trace_file = _open_trace(trace) if own_file else trace
    bus = open_bus(interface, channel, **(bus_kwargs or {}))
    name = f"{interface}:{channel}"
    if in_process_only(interface):
        messages.warning(f"{name}: {in_process_only(interface)}")
    source = CanBusSource(bus, db, smap, idle_timeout_s=idle_timeout, start_timeout_s=start_timeout, name=name,
                          on_problem=lambda line: messages.warning(f"{name}: {line}"))
    source.move_lateral_velocity(car.sensor_position("lateral_velocity_x_m"))
    estimator = make_estimator(car, filter, prior=prior_values, prior_relative_std=prior_rel,
                               config=filter_config(correct_every, intersample=intersample), effects=effect_list,
                               offsets=offset_channels(offsets, smap.signals), channels=tuple(smap.signals))
    stats = source.assembler.stats
    rows = StreamedTrace(trace_file, keep=LIVE_TRACE_ROWS)
    messages.result(f"listening on {name} with {smap.name} frames, {filter.upper()} (Ctrl-C to stop)")
    try:
        # live: estimate at once, judge alongside; a failed check ends the run before anything is reported
        checker = StreamChecker(car.known, car.prior, allow=parse_allow(allow_implausible), max_window_s=check_window,
                                source=name, on_notes=lambda lines: [messages.warning(x) for x in lines], hold=False)
        hook = None if on_sample is None else (lambda est, sample: on_sample(est, sample, stats))
        result = run_estimator(estimator, checker.check(source), source=name, channels=list(smap.signals),
                               on_sample=hook, trace_rows=rows)
    finally:
        rows.flush()  # what was estimated is in the file however the run ended
        if own_file:
            trace_file.close()
        try:
            source.close()
        except OnlineIdError as exc:
            messages.warning(str(exc))
    if result.interrupted:
        source.ended_by = "interrupted"
    result.consistency = with_informed(result.consistency, result.informed, result.fixed,
                                       result.events.get("corrections", 0))
    result.source_report = {"ended_by": source.ended_by, "frames": source.report(), "bus": name,
                            "receive_buffer_bytes": source.receive_buffer_bytes,
                            "backlog_stops": source.backlog_stops}  # the estimator at MAX_BACKLOG_FRAMES behind
    if len(source.lag_s):
        lag = source.lag_s.values()
        result.source_report["lag_s"] = {"p50": float(np.percentile(lag, 50)), "p99": float(np.percentile(lag, 99))}
    for line in source.problems():
        messages.warning(f"{name}: {line}")
    # loss at the top level of the JSON, beside the frame counts (details in source_report.frames)
    loss = {"lost_samples": stats.lost_samples, "lost_samples_fraction": round(stats.loss_fraction(), 6),
            "lost_by_signal": stats.lost_by_signal, "frames_received": stats.frames,
            "frames_lost": sum(stats.lost_frames.values()), "lost_frames_by_message": dict(stats.lost_frames)}
    return Listening(result, messages.of("warning"), messages, name=name, loss=loss, ended_by=source.ended_by,
                     nothing_arrived=bool(source.nothing_arrived), frames=stats.frames, samples_made=stats.samples)


def _open_trace(path):
    try:
        return open(path, "w", encoding="utf-8")
    except OSError as exc:
        raise OnlineIdError(f"trace {path}: cannot write: {exc.strerror or exc}") from None
