"""The estimate workflow: the online filter over a whole log (any format) or the built-in run, the
plausibility checks before it, the batch polish after it, the cross-check against a prior.

One path for every front end: ``online-id estimate``, ``online_id.estimate`` and ``online-id batch``
all call :func:`estimate`. A log in any format is a whole run, so it gets the same default polish
(issue 26: the same samples give the same answer from a CSV, a parquet table, a CAN log or an MDF
file); only a live bus (:mod:`online_id.workflows.listen`) stays filter-only.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator

import numpy as np

from online_id.errors import OnlineIdError
from online_id.io.tracklog import TrackRun
from online_id.stream.samples import Sample, SampleArrays
from online_id.trust.consistency import with_informed
from online_id.vehicle.parameters import PARAMETER_NAMES
from online_id.workflows.derived import handling_of
from online_id.workflows.inputs import (
    builtin_run,
    check_effects_act,
    filter_config,
    filter_effects_of,
    input_run,
    input_source,
    intersample_of,
    mended,
    offset_channels,
    parse_fix,
    plausibility_of,
    prior_of,
    run_truth,
    say_run_notes,
    say_unused_columns,
    vehicle_of,
)
from online_id.workflows.messages import Messages
from online_id.workflows.results import Estimate

#: |z| above which the filter and a prior fit disagree (difference in combined σ).
DISAGREE_Z = 3.0
#: A parameter not informed that moved less than this many prior σ from a fit it started from still has the
#: fit's value: it is not compared with it (z ≈ 0 is no agreement).
NOT_MOVED_PRIOR_SIGMA = 0.05


def polish_wanted(polish: bool | None, *, extended: bool) -> bool:
    """Whether to polish: on by default for a whole run (any offline log, or the built-in run), with or
    without effects (the polish fits theirs with the 8) and with fixed parameters (held where the filter held
    them); asked for (``polish=True``) with offset states (``extended``), which the batch polish does not model,
    it is an error."""
    if polish and extended:
        raise OnlineIdError("--polish fits the 8 parameters and the effects' own: it cannot be combined with"
                            " --offsets")
    return polish is not False and not extended


def estimate(source=None, *, vehicle=None, filter: str = "ekf", prior=None, channels=None,
             correct_every: int | None = None, keep_prior_std: bool = False, fixed=None, effects=(),
             effects_from=None, offsets: bool = False, polish: bool | None = None,
             allow_implausible: str | None = None, dbc=None, signals=None, can_channel=None, drop_nan: bool = False,
             resample: float | None = None, intersample: str | None = None, progress: bool = False,
             messages: Messages | None = None) -> Estimate:
    """Online estimate of the 8 parameters (``online-id estimate``).

    Parameters
    ----------
    source : path (track-run CSV or parquet, a CAN log in any python-can format, an MDF file), a pandas
        DataFrame with the track-run columns (SI), a TrackRun, or None for the built-in run
    vehicle : built-in name or TOML path (or a loaded Vehicle)
    filter : ``"ekf"`` or ``"ukf"``
    prior : fit or estimate JSON path, or a Fit / Estimate to start from
    channels : measured channels to use, ``"yaw_rate,lateral_acceleration"`` or a list (default: all present)
    correct_every : correct every k-th sample (default: the filter's 20)
    keep_prior_std : start from the vehicle file's prior σ as written (``--keep-prior-std``)
    fixed : ``["Mzz=1600", "b1"]`` (``--fix``) or ``{"Mzz": 1600.0}`` [SI]: held fixed
    effects : ``NAME[:CHANNEL][:START]`` strings (``--effect``) or Effect instances
    effects_from : a ``diagnose --json`` path or a Diagnosis (``--effects-from``)
    offsets : learn the sensor offsets as filter states (``--offsets``)
    polish : batch-polish the filter's estimate over the whole run (default: on, unless offsets or fixed
        parameters are asked for)
    allow_implausible : plausibility checks to accept, e.g. ``"yaw_sign"`` or ``"all"``
    dbc, signals, can_channel : how to decode a CAN log (default: online-id's own frames); ``signals`` also names
        a column map for a CSV or Parquet table of a logger's own columns (drivers/column_map.py)
    drop_nan : drop a table's rows with NaN, inf or empty cells, counted and said (``--drop-nan``)
    resample : put the log on an even grid at this rate [Hz] first (``--resample``): a CAN log's trigger frames
        arrive unevenly, and the polish needs one step (without it a CAN log is never polished)
    intersample : the steering between samples the filter and the polish take, ``"hold"``, ``"linear"`` or
        ``"cubic"`` (``--intersample``; default :attr:`~online_id.filters.FilterConfig.intersample`)
    progress : a progress bar on stderr
    messages : where the run's lines go as they come (default: kept on the result only)

    Notes
    -----
    The consistency verdict is ``est.result.consistency`` (``"consistency"`` in ``to_json()``).
    """
    from online_id.drivers.csv_source import TrackRunSource
    from online_id.drivers.sources import only_channels, record_source, select_channels
    from online_id.estimation import make_estimator, run_estimator
    from online_id.trust.spikes import mend_samples

    messages = messages if messages is not None else Messages()
    car = vehicle_of(vehicle)
    intersample = intersample_of(intersample)
    prior_values, prior_rel = prior_of(prior)
    fixed = parse_fix(fixed, prior_values or car.prior)
    effect_list = filter_effects_of(effects, effects_from, car.known, messages)  # before any data is read
    if source is None:
        src = TrackRunSource(run=builtin_run(car, messages))
    elif resample:  # a decoded log on an even grid: a whole table, polished like any (issue 39)
        src = TrackRunSource(run=input_run(source, car, dbc=dbc, signals=signals, can_channel=can_channel,
                                          drop_nan=drop_nan, resample=resample, messages=messages)[0])
    else:
        src = input_source(source, dbc, signals, can_channel, drop_nan)
        src.move_lateral_velocity(car.sensor_position("lateral_velocity_x_m"))  # (a table's run: input_run's way)
    spikes: list = []  # input glitches mended (online_id.trust.spikes): a table's now, a stream's as it passes
    if getattr(src, "run", None) is not None:  # a table: its input glitches mended before the filter sees them
        table, spikes = mended(src.run)
        if spikes:
            src = TrackRunSource(run=table)
    chosen = select_channels(channels, src)
    check_effects_act(effect_list, chosen, src.name)
    config = filter_config(correct_every, keep_prior_std, chosen if channels is not None else None, intersample)
    wanted = polish_wanted(polish, extended=bool(offsets))
    estimator = make_estimator(car, filter, prior=prior_values, prior_relative_std=prior_rel, config=config,
                               fixed=fixed, effects=effect_list, offsets=offset_channels(offsets, chosen),
                               channels=chosen)
    notes = estimator.prior_spread.notes()
    run = getattr(src, "run", None)  # a table: its length and its truth are known
    if run is not None and not resample:  # (input_run said it for a resampled log)
        say_unused_columns(run, messages)
    label = src.name
    samples: Iterable[Sample] | SampleArrays = src if chosen == src.channels else only_channels(src, chosen)
    plausibility = None
    if run is not None:
        plausibility = plausibility_of(run, car, allow_implausible, messages)
        samples = src.arrays(chosen)  # a whole table: the filter's array path (the same numbers, faster)
    else:  # a CAN or MDF log: its samples are held until judged
        from online_id.trust.plausibility import StreamChecker, parse_allow

        samples = StreamChecker(car.known, car.prior, allow=parse_allow(allow_implausible), max_window_s=None,
                                source=label, on_notes=lambda lines: [messages.warning(x) for x in lines]
                                ).check(samples)
        samples = mend_samples(samples, spikes)
    recorded: list[Sample] | None = [] if run is None else None  # a streamed log's run: the polish, the handling
    if recorded is not None:
        samples = _recording(samples, recorded)
    with src:
        result = run_estimator(estimator, samples, total=len(run) if run is not None else None,
                               progress=progress and run is not None, source=label,
                               truth=run_truth(run) if run is not None else None, channels=chosen)
    source_warnings = record_source(result, src, chosen)
    say_run_notes(vehicle, car, label if source is not None else None, run, spikes, messages)  # said with a result
    result.input_spikes = [sp.to_json_dict() for sp in spikes]
    result.plausibility = plausibility.to_dict() if plausibility is not None else None
    whole = run if run is not None else _run_of(recorded, label, chosen)
    if wanted and not result.interrupted:
        _polish(result, car, whole, label, config, effect_list, messages, progress)
    if prior_values is not None:
        result.cross_check = cross_check(result, prior_values, prior_rel)
    result.consistency = with_informed(result.consistency, result.informed, result.fixed,  # σ final here
                                       result.events.get("corrections", 0))
    _fit_what_was_left_out(result.consistency, effects_from)
    result.handling = _handling(result, car, whole if isinstance(whole, TrackRun) else None, messages)
    result.vehicle = {"name": car.name, "given": vehicle is not None}
    for line in notes:
        messages.note(line)
    for line in source_warnings:
        messages.warning(f"{label}: {line}")
    return Estimate(result, messages.of("warning"), messages, notes=list(notes), label=label)


def _fit_what_was_left_out(consistency: dict | None, effects_from) -> None:
    """A verdict that failed while the diagnosis named effects the filters cannot carry (``carry.not_online``): its
    first next step is the batch fit that carries them, not another diagnosis (which would name them again)."""
    from online_id.diagnosis.carry import not_online_of

    left_out = not_online_of(effects_from)
    if not left_out or not consistency or consistency.get("consistent") is not False:
        return
    path = effects_from if isinstance(effects_from, (str, os.PathLike)) else "DIAG.json"
    step = {"lever": "fit", "run": ["online-id", "fit", "LOG", "--effects-from", str(path)],
            "because": f"the diagnosis named {', '.join(left_out)}, which the filters cannot carry yet (the data"
                       " hold it, this estimate does not): the batch fit carries it"}
    consistency["next_steps"] = [step, *(s for s in consistency.get("next_steps", []) if s.get("lever") != "structure")]


def _recording(samples: Iterable[Sample], into: list[Sample]) -> Iterator[Sample]:
    """``samples`` as they pass, kept in ``into`` (a streamed log's whole run, for the polish)."""
    for s in samples:
        into.append(s)
        yield s


def _handling(result, car, run: TrackRun | None, messages: Messages):
    """The handling metrics of the estimate (its covariance after every widening), at the run's median speed,
    with the run's response measured; without a run (a stream that gave none), at the trace's median speed."""
    speed = None
    if run is None:
        trace_speed = result.trace.speed
        speed = float(np.median(trace_speed)) if trace_speed is not None and len(trace_speed) else float("nan")
    return handling_of(result.parameters, result.covariance, car, run=run, speed_mps=speed, messages=messages)


def _run_of(recorded: list[Sample] | None, label: str, channels) -> TrackRun | OnlineIdError | None:
    """The whole run of a streamed log from the samples it gave (None when nothing was recorded), or the
    OnlineIdError that says why it is not one (a log without lateral acceleration, ...)."""
    if recorded is None:
        return None
    from online_id.drivers.sources import run_from_samples

    try:
        return run_from_samples(recorded, label, channels)[0]
    except OnlineIdError as exc:
        return exc


def _polish(result, car, run, label, config, effects, messages: Messages, progress: bool = False) -> None:
    """The batch polish of the filter's estimate (online_id.batchfit.polish), over the run (a table's own,
    or the one a streamed log's samples made, or the error that says why there is none)."""
    from online_id.batchfit.polish import POLISH_BURN_IN_S, polish_estimate

    if isinstance(run, OnlineIdError) or run is None:
        reason = run if run is not None else "no sample was recorded"
        result.polish = {"error": f"not polished: {reason}"}
        messages.warning(f"{label}: not polished: {reason}")
        return
    problem = polish_estimate(result, car, run, config.measurement_std, burn_in_s=POLISH_BURN_IN_S,
                              prior_log_std_floor=config.prior_log_std_floor, effects=effects, progress=progress,
                              intersample=config.intersample)
    if problem:
        where = "" if problem.startswith(f"{run.source}:") else f"{run.source}: "
        if "evenly sampled" in problem:  # a CAN log's trigger frames: say the way to get the polish
            rate = 1.0 / float(np.median(np.diff(run.time)))
            problem += f"; --resample {_round_rate(rate):g} puts the log on an even grid and polishes it"
        messages.warning(f"{where}{problem}")
        return
    p = result.polish
    messages.result(f"polished the {result.filter.upper()} estimate by a batch fit over the whole run:"
                    f" {p['iterations']} evaluations, {p['wall_s']:.2f} s;"
                    + (f" {', '.join(p['started_at_prior'])} started at the prior (the filter did not inform them);"
                       if p.get("started_at_prior") else "")
                    + f" covariance ×"
                    f" {p['covariance_inflation']:.2f} for correlated residuals")


def _round_rate(rate_hz: float) -> float:
    """A rate to suggest for ``--resample``: the log's median rate, rounded down to 2 significant digits."""
    digits = 10 ** max(0, int(np.floor(np.log10(max(rate_hz, 1.0)))) - 1)
    return float(np.floor(rate_hz / digits) * digits)


def cross_check(result, prior, prior_rel, *, started_from: bool = True) -> dict:
    """Per parameter: the filter's final value against the prior's (a fit's), in combined σ.

    ``started_from``: the filter started from that fit (``estimate --prior``). Then every parameter once it
    diverged (held at the prior), a fixed one, and one it neither informed nor moved (under
    :data:`NOT_MOVED_PRIOR_SIGMA`) has the fit's own value: z = 0 would read as perfect agreement (issue 39: the
    race car's filter diverged at 1 s and printed z = +0.00 for all 8). Such a parameter is not compared:
    ``compared`` False, ``z`` None, ``not_compared_because`` says why."""
    diverged = result.events.get("diverged", 0) > 0 and result.online is None  # (a polish after it moves on)
    informed, moved = result.informed, result.moved_prior_sigma
    out = {}
    for i, n in enumerate(PARAMETER_NAMES):
        est, sd = float(result.parameters.to_vector()[i]), float(result.std[i])
        fit = float(prior.to_vector()[i])
        fit_sd = fit * float(prior_rel[i]) if np.isfinite(prior_rel[i]) else float("inf")
        z = (est - fit) / np.hypot(sd, fit_sd)
        why = None
        if started_from and diverged:
            why = "the filter diverged and fell back to its prior, this fit: its value is the fit's own"
        elif started_from and n in result.fixed:
            why = "held fixed"
        elif started_from and not informed.get(n, True) and moved[i] < NOT_MOVED_PRIOR_SIGMA:
            why = "not informed by this run and not moved: the filter's value is its prior's, this fit's"
        out[n] = {"estimate": est, "fit": fit, "fit_std": fit_sd if np.isfinite(fit_sd) else None,
                  "z": None if why else float(z), "disagree": bool(why is None and abs(z) > DISAGREE_Z),
                  "compared": why is None}
        if why:
            out[n]["not_compared_because"] = why
    return out
