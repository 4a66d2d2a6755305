"""The convergence workflow: one filter over one run from several initial covariances and values
(``online-id plot convergence``); the figure is drawn by :mod:`online_id.plots.convergence`."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

from online_id.errors import OnlineIdError
from online_id.workflows.inputs import (
    filter_config,
    input_run,
    mended,
    prior_of,
    run_truth,
    say_run_notes,
    vehicle_of,
)
from online_id.workflows.messages import Messages
from online_id.workflows.results import Convergence


def convergence(source=None, *, vehicle=None, filter: str = "ekf", prior=None, channels=None,
                correct_every: int | None = None, p0_scales: Sequence[float] = (1.0,),
                init_scales: Sequence[float] = (), dbc=None, signals=None, can_channel=None, drop_nan: bool = False,
                resample: float | None = None, intersample: str | None = None, progress: bool = False,
                messages: Messages | None = None) -> Convergence:
    """Run the filter once per initial-covariance scale (``p0_scales``: the initial parameter variance × S)
    and per initial value (``init_scales``: F × the truth of a simulated run, else × the prior); with a
    ``prior``, also once from the vehicle's constructor prior for comparison. Stops at an interruption,
    keeping the runs done. ``intersample``: the steering between samples (``--intersample``)."""
    from online_id.drivers.sources import select_channels
    from online_id.estimation import make_estimator, run_estimator
    from online_id.stream.samples import SampleArrays
    from online_id.workflows.inputs import input_source

    messages = messages if messages is not None else Messages()
    car = vehicle_of(vehicle)
    prior_values, prior_rel = prior_of(prior)
    run, _ = input_run(source, car, dbc=dbc, signals=signals, can_channel=can_channel, drop_nan=drop_nan,
                      resample=resample,
                      messages=messages)
    run, spikes = mended(run)
    chosen = select_channels(channels, input_source(run))
    truth = run_truth(run)
    base = filter_config(correct_every, intersample=intersample)
    p0_scales, init_scales = list(p0_scales or [1.0]), list(init_scales or [])
    if any(s <= 0 for s in p0_scales + init_scales):
        raise OnlineIdError("--p0-scale and --init-scale must be positive")
    centre = truth or prior_values or car.prior
    from_prior = f" from {_name(prior)}" if prior_values is not None else ""
    cases = [(f"P0 × {s:g}{from_prior}", replace(base, p0_scale=s), None) for s in p0_scales]
    cases += [(f"start {f:g} × {'truth' if truth else 'prior'}", base, centre.scaled(f)) for f in init_scales]
    if prior_values is not None:  # the reference: the same filter from the vehicle's constructor prior
        cases.append(("constructor prior", base, "constructor"))
    runs = []
    for label, config, initial in cases:
        if initial == "constructor":
            est = make_estimator(car, filter, config=config, channels=chosen)
        else:
            est = make_estimator(car, filter, prior=prior_values, prior_relative_std=prior_rel, initial=initial,
                                 config=config, channels=chosen)
        messages.status(f"running {label} ...")
        res = run_estimator(est, SampleArrays.from_run(run, tuple(chosen)), total=len(run), progress=progress,
                            source=run.source, truth=truth, channels=chosen)
        runs.append((label, res))
        if res.interrupted:
            break
    say_run_notes(vehicle, car, source, run, spikes, messages)
    return Convergence(runs, messages.of("warning"), messages, truth=truth, channels=chosen, source=run.source)


def _name(prior) -> str:
    """How a prior is named in a case's label: its file name, else "the prior"."""
    from pathlib import Path

    return Path(prior).name if isinstance(prior, (str, Path)) else "the prior"
