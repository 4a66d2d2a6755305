"""The report workflow: every job over one run, gathered for one page (``online-id report``).

It calls the other workflows exactly as their commands do (``check``, ``estimate``, ``fit``,
``diagnose``: the same defaults), so the command lines it lists reproduce each part, and adds what only
the parts together can say: the fit's agreement with the estimate (z per parameter), the run's
excitation window by window (:mod:`online_id.trust.over_time`), the innovations against their spread.
The page itself is drawn by :mod:`online_id.report`; a part that fails is an error on its section, the
others are still made.
"""

from __future__ import annotations

import shlex
import time
from pathlib import Path

import numpy as np

from online_id.errors import OnlineIdError
from online_id.util.interrupts import interrupt_inside
from online_id.workflows.inputs import DEFAULT_VEHICLE, input_run, mended, say_default_vehicle, vehicle_of
from online_id.workflows.messages import Messages
from online_id.workflows.results import Report

#: The parts of a report, in the order they run and appear.
PARTS = ("check", "estimate", "fit", "diagnose")


def report(source=None, *, vehicle=None, filter: str = "ekf", fit: bool = True, diagnose: bool = True,
           generations: int | None = None, effects=None, allow_implausible: str | None = None, dbc=None,
           signals=None, can_channel=None, drop_nan: bool = False, resample: float | None = None,
           intersample: str | None = None, progress: bool = False,
           out: str | Path | None = None, messages: Messages | None = None) -> Report:
    """Check, estimate, fit and diagnose one run, for one page (``online-id report``).

    Parameters
    ----------
    source : any log ``estimate`` reads (a path), a DataFrame, a TrackRun, or None for the built-in run
    vehicle, filter, allow_implausible, dbc, signals, can_channel : as in
        :func:`~online_id.workflows.estimate_job.estimate`
    fit, diagnose : run the batch fit, the gap diagnosis (each takes minutes on a long log)
    generations : the fit's GA generations (default: the fit's)
    effects : the diagnosis's candidates, ``"a,b"`` or a list (default: every registered effect)
    resample : put a decoded CAN log on an even grid at this rate [Hz] for every part (the estimate too)
    intersample : the steering between samples every part takes (``--intersample``; as in
        :func:`~online_id.workflows.estimate_job.estimate`)
    progress : a status line per part, and the parts' own progress
    out : where the page will be written (only for the command line that remakes it)
    messages : where the run's lines go as they come (a warning repeated by several parts is passed once)
    """
    from online_id import workflows
    from online_id.workflows.estimate_job import cross_check

    messages = messages if messages is not None else Messages()
    car = vehicle_of(vehicle)
    decode = {"dbc": dbc, "signals": signals, "can_channel": can_channel, "drop_nan": drop_nan}
    wanted = [p for p in PARTS if {"fit": fit, "diagnose": diagnose}.get(p, True)]
    rep = Report(None, messages=messages, source=_label(source), vehicle=car.name,
                 commands=commands(source, vehicle=vehicle, filter=filter, fit=fit, diagnose=diagnose,
                                   generations=generations, effects=effects, allow_implausible=allow_implausible,
                                   resample=resample, intersample=intersample, out=out, **decode),
                 skipped=[p for p in PARTS if p not in wanted])
    rep.run, _ = mended(input_run(source, car, resample=resample, messages=Messages(), **decode)[0])
    jobs = {
        "check": lambda m: workflows.check(source, vehicle=car, resample=resample, intersample=intersample,
                                           messages=m, **decode),
        "estimate": lambda m: workflows.estimate(source, vehicle=car, filter=filter,
                                                 allow_implausible=allow_implausible, resample=resample,
                                                 intersample=intersample,
                                                 progress=progress, messages=m, **decode),
        "fit": lambda m: workflows.fit(source, vehicle=car, generations=generations,
                                       allow_implausible=allow_implausible, resample=resample,
                                       intersample=intersample, progress=progress, messages=m, **decode),
        "diagnose": lambda m: workflows.diagnose(source, vehicle=car, effects=effects,
                                                 allow_implausible=allow_implausible, resample=resample,
                                                 intersample=intersample, progress=progress, messages=m, **decode),
    }
    seen: set[tuple[str, str]] = set()
    for i, part in enumerate(wanted, 1):
        messages.status(f"[{i}/{len(wanted)}] {part} ...")
        t0 = time.perf_counter()
        try:
            result = jobs[part](_once(messages, seen))
        except OnlineIdError as exc:
            if part == "estimate":  # the report is about the estimate: without it there is nothing to show
                raise
            rep.errors[part] = str(exc)
            messages.warning(f"{part}: {exc}")
            continue
        except (KeyboardInterrupt, SystemError) as exc:
            if interrupt_inside(exc) is None:
                raise
            rep.interrupted = part
            break
        finally:
            rep.wall_s[part] = round(time.perf_counter() - t0, 2)
        result.messages = Messages(lines=list(result.messages.lines))  # its lines, not the echo to the front end
        setattr(rep, {"diagnose": "diagnosis"}.get(part, part), result)
        messages.status(f"[{i}/{len(wanted)}] {part} done in {rep.wall_s[part]:.1f} s")
        if getattr(result.result, "interrupted", False) or getattr(result, "interrupted", False):
            rep.interrupted = part
            break
    if rep.estimate is None:
        raise KeyboardInterrupt  # interrupted before the estimate: nothing to report
    say_default_vehicle(vehicle, car, source, rep.run, messages)  # once here: the parts are given the car (they
    # say the input spikes themselves, once: _once)
    if rep.check is not None:
        rep.excitation = rep.check.result.excitation
    tr = rep.estimate.result.trace
    from online_id.trust.over_time import innovation_windows, learned_by_window

    rep.learned = learned_by_window(tr.time, tr.values, tr.std,
                                    rep.excitation.window_s if rep.excitation is not None else None)
    rep.innovations = innovation_windows(rep.estimate.result.innovations)
    if rep.fit is not None:
        f = rep.fit.result
        values = f.parameters.to_vector()
        rel = np.where(np.isfinite(f.std), np.asarray(f.std, dtype=float) / values, np.nan)
        rep.agreement = cross_check(rep.estimate.result, f.parameters, rel, started_from=False)
    return rep


def _once(parent: Messages, seen: set) -> Messages:
    """A part's Messages: every line goes to ``parent``, but a warning or note another part already gave
    (the plausibility checks run before each) only once."""
    def echo(kind: str, line: str) -> None:
        if kind in ("warning", "note"):
            if (kind, line) in seen:
                return
            seen.add((kind, line))
        parent._add(kind, line)

    return Messages(echo=echo)


def _label(source) -> str:
    if source is None:
        return "the built-in run"
    if isinstance(source, (str, Path)):
        return str(source)
    return getattr(source, "source", "") or type(source).__name__


def commands(source=None, *, vehicle=None, filter: str = "ekf", fit: bool = True, diagnose: bool = True,
             generations: int | None = None, effects=None, allow_implausible: str | None = None, dbc=None,
             signals=None, can_channel=None, drop_nan: bool = False, resample: float | None = None,
             intersample: str | None = None,
             out: str | Path | None = None) -> dict[str, str]:
    """The command line that reproduces each part of a report made with these arguments (``{part: line}``;
    ``report``: the page itself). A source that is not a path (a DataFrame) has no command line: None."""
    if source is not None and not isinstance(source, (str, Path)):
        return {}
    log = [] if source is None else [str(source)]
    common = ["--vehicle", str(vehicle)] if vehicle is not None and str(vehicle) != DEFAULT_VEHICLE else []
    common += [a for flag, v in (("--dbc", dbc), ("--signals", signals), ("--can-channel", can_channel),
                                 ("--intersample", intersample)) if v is not None for a in (flag, str(v))]
    common += ["--drop-nan"] if drop_nan else []
    allow = ["--allow-implausible", allow_implausible] if allow_implausible else []
    grid = ["--resample", f"{resample:g}"] if resample else []
    filt = ["--filter", filter] if filter != "ekf" else []
    gens = ["--generations", str(generations)] if generations is not None else []
    cands = ["--effects", effects if isinstance(effects, str) else ",".join(effects)] if effects else []

    def line(*words) -> str:
        return shlex.join(["online-id", *words])

    out_path = str(out) if out is not None else "RUN.html"
    switches = ([] if fit else ["--no-fit"]) + ([] if diagnose else ["--no-diagnose"])
    lines = {
        "check": line("check", *log, *common, *grid, "--json", "check.json"),
        "estimate": line("estimate", *log, *common, *filt, *allow, *grid, "--json", "estimate.json",
                         "--trace", "trace.csv"),
        "fit": line("fit", *log, *common, *gens, *allow, *grid, "--json", "fit.json"),
        "diagnose": line("diagnose", *log, *common, *cands, *allow, *grid, "--json", "diagnose.json",
                         "--report", "diagnosis-figures"),
        "report": line("report", *log, *common, *filt, *gens, *cands, *allow, *grid, *switches, "--out", out_path),
    }
    return lines
