"""The diagnosis workflow: the sim-to-real gap of a run (``online-id diagnose``, ``online_id.diagnose``,
``batch --diagnose``), with the plausibility checks before it."""

from __future__ import annotations

from online_id.errors import OnlineIdError
from online_id.workflows.inputs import (
    input_run,
    intersample_of,
    mended,
    only_run_channels,
    plausibility_of,
    say_run_notes,
    vehicle_of,
)
from online_id.workflows.messages import Messages
from online_id.workflows.results import Diagnosis


def effect_names(effects) -> list[str] | None:
    """Candidate names from ``"a,b"`` (``--effects``) or a list, checked against the registry; None: all."""
    from online_id.effects import EFFECTS

    if effects is None:
        return None
    names = [n.strip() for n in (effects.split(",") if isinstance(effects, str) else effects) if str(n).strip()]
    unknown = [n for n in names if n not in EFFECTS]
    if unknown:
        raise OnlineIdError(f"--effects: unknown {', '.join(unknown)}; choose from {', '.join(EFFECTS)}")
    return names or None


def diagnose(source=None, *, vehicle=None, validate=None, effects=None, channels=None,
             allow_implausible: str | None = None,
             dbc=None, signals=None, can_channel=None, drop_nan: bool = False,
             resample: float | None = None, intersample: str | None = None, progress: bool = False,
             messages: Messages | None = None) -> Diagnosis:
    """The sim-to-real gap (``online-id diagnose``).

    Parameters
    ----------
    source : any log ``estimate`` reads, a DataFrame, a TrackRun, or None for the built-in run
    validate : a second run to judge the fits on (default: held-out segments of ``source``)
    effects : candidates to try, ``"a,b"`` or a list (default: every registered effect)
    channels : the measured channels to judge the model on, ``"a,b"`` or a list (``--channels``; default: all the
        log has); the others are left out of every fit
    allow_implausible : plausibility checks to accept (``--allow-implausible``)
    dbc, signals, can_channel, resample : how to decode a CAN log, and an even grid for it [Hz]
    intersample : the steering between samples every model takes (``--intersample``; as
        :func:`~online_id.workflows.estimate_job.estimate`)
    progress : report each candidate as it is fitted (a ``status`` message ``[i/n] what``)
    messages : where the run's lines go as they come
    """
    from online_id.diagnosis.diagnose import diagnose_gap
    from online_id.diagnosis.kinematics import kinematics_of

    messages = messages if messages is not None else Messages()
    car = vehicle_of(vehicle)
    intersample = intersample_of(intersample)
    names = effect_names(effects)
    options = {"dbc": dbc, "signals": signals, "can_channel": can_channel, "drop_nan": drop_nan, "resample": resample}
    run, spikes = mended(input_run(source, car, messages=messages, **options)[0])
    held = None if validate is None else mended(input_run(validate, car, messages=messages, **options)[0])[0]
    read = run, held  # (the kinematics check reads the data, whatever is judged)
    if channels is not None:
        run, held = (None if r is None else only_run_channels(r, channels) for r in (run, held))
    for r in (run, held):
        if r is not None:
            plausibility_of(r, car, allow_implausible, messages)

    def tick(what, i, n):
        if progress:
            messages.status(f"[{i}/{n}] {what}")

    result = diagnose_gap(car, run, held, progress=tick, effects=names, intersample=intersample)
    if result.remaining is not None and run.lateral_velocity is None:  # (--channels left it out of the fits)
        entry = kinematics_of(*read)
        result.remaining["lateral_kinematics"] = None if entry is None else {**entry, "judged": False}
    say_run_notes(vehicle, car, source, run, spikes, messages)
    return Diagnosis(result, messages.of("warning"), messages)
