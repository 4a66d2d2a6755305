"""The fit workflow: Haro's hybrid-GA batch fit of a whole run (``online-id fit``, ``online_id.fit``,
``batch --fit``), with the plausibility checks before it."""

from __future__ import annotations

from dataclasses import replace

from online_id.errors import OnlineIdError
from online_id.stream.samples import MEASURED_CHANNELS
from online_id.workflows.derived import handling_of
from online_id.workflows.inputs import (
    check_effects_act,
    effects_of,
    input_run,
    intersample_of,
    mended,
    parse_fix,
    plausibility_of,
    run_truth,
    say_run_notes,
    vehicle_of,
)
from online_id.workflows.messages import Messages
from online_id.workflows.results import Fit

#: Search bounds as factors of the prior (``--bounds``).
DEFAULT_BOUNDS = (0.2, 5.0)


def fit(source=None, *, vehicle=None, generations: int | None = None, groups: int | None = None,
        bounds: tuple[float, float] = DEFAULT_BOUNDS, seed: int = 0, fixed=None, effects=(), effects_from=None,
        allow_implausible: str | None = None, dbc=None, signals=None, can_channel=None, drop_nan: bool = False,
        resample: float | None = None, intersample: str | None = None, progress: bool = False,
        messages: Messages | None = None) -> Fit:
    """Batch fit with Haro's hybrid GA (``online-id fit``).

    Parameters
    ----------
    source : any log ``estimate`` reads, a DataFrame, a TrackRun, or None for the built-in run
    generations, groups : the GA's (default :class:`~online_id.batchfit.ga.GAConfig`'s)
    seed : the GA's seed
    bounds : (low, high) search bounds as factors of the prior, 0 < low < 1 < high
    fixed : ``["Mzz=1600"]`` or ``{"Mzz": 1600.0}`` held fixed (left out of the search)
    effects, effects_from : as in :func:`~online_id.workflows.estimate_job.estimate` (the fit takes every
        block-mean form, so every effect a diagnosis named)
    allow_implausible : plausibility checks to accept (``--allow-implausible``)
    dbc, signals, can_channel : how to decode a CAN log
    resample : put a decoded log on an even grid at this rate [Hz]
    intersample : the steering between samples the model takes (``--intersample``; as
        :func:`~online_id.workflows.estimate_job.estimate`)
    progress : a progress bar on stderr
    messages : where the run's lines go as they come
    """
    from online_id.batchfit.fit import FitConfig, fit_run
    from online_id.batchfit.ga import GAConfig

    messages = messages if messages is not None else Messages()
    car = vehicle_of(vehicle)
    intersample = intersample_of(intersample)
    ga = GAConfig()
    ga = replace(ga, generations=ga.generations if generations is None else int(generations),
                 groups=ga.groups if groups is None else int(groups))
    if ga.generations < 1 or ga.groups < 1:
        raise OnlineIdError("--generations and --groups must be at least 1")
    low, high = bounds
    if not 0 < low < 1 < high:
        raise OnlineIdError(f"--bounds must satisfy 0 < LOW < 1 < HIGH, got {low:g} {high:g}")
    fixed = parse_fix(fixed, car.prior)
    effect_list = effects_of(effects, effects_from, online=False, messages=messages)
    run, _ = input_run(source, car, dbc=dbc, signals=signals, can_channel=can_channel, drop_nan=drop_nan,
                      resample=resample,
                      messages=messages)
    run, spikes = mended(run)
    check_effects_act(effect_list, [c for c in MEASURED_CHANNELS if getattr(run, c) is not None], run.source)
    plausibility_of(run, car, allow_implausible, messages)
    if fixed:
        messages.note("held fixed (left out of the search): " + ", ".join(f"{n} = {v:.6g}" for n, v in fixed.items()))
    config = FitConfig(lower_factor=low, upper_factor=high, ga=ga, intersample=intersample)
    result = fit_run(car, run, config, seed=seed, truth=run_truth(run), progress=progress, fixed=fixed,
                     effects=effect_list)
    say_run_notes(vehicle, car, source, run, spikes, messages)
    handling = None if result.interrupted else handling_of(result.parameters, result.covariance, car, run=run,
                                                           messages=messages)
    return Fit(result, messages.of("warning") + list(result.warnings), messages, handling=handling)
