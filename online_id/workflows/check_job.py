"""The check workflow: what a run can tell before any estimate (``online-id check``, ``online_id.check``)."""

from __future__ import annotations

from online_id.errors import OnlineIdError
from online_id.workflows.inputs import input_run, intersample_of, mended, prior_of, say_run_notes, vehicle_of
from online_id.workflows.messages import Messages
from online_id.workflows.results import Check


def check(source=None, *, vehicle=None, prior=None, dbc=None, signals=None, can_channel=None, drop_nan: bool = False,
          resample: float | None = None, intersample: str | None = None, messages: Messages | None = None) -> Check:
    """Sampling, channels, speed, steering spectrum, |a_y|, the Cramér-Rao bound per parameter (linearised at
    the vehicle's prior, or at ``prior``: a fit JSON path or a Fit/Estimate), and what manoeuvre or channel
    would determine what the run cannot. ``source`` and ``intersample`` (the steering between samples the
    sensitivities take) as in :func:`~online_id.workflows.estimate_job.estimate`."""
    from online_id.trust.check import check_run

    messages = messages if messages is not None else Messages()
    car = vehicle_of(vehicle)
    intersample = intersample_of(intersample)
    theta, where = car.prior, f"the prior of {car.name}"
    if prior is not None:
        theta, _ = prior_of(prior)
        where = str(prior)
    run, _ = input_run(source, car, dbc=dbc, signals=signals, can_channel=can_channel, drop_nan=drop_nan,
                      resample=resample,
                      messages=messages)
    if len(run) < 2:
        raise OnlineIdError(f"{run.source}: too short to check")
    run, spikes = mended(run)  # what the run can tell, without a glitch's false excitation
    report = check_run(run, car, theta, linearised_at=where, intersample=intersample)
    report.input_spikes = [s.to_json_dict() for s in spikes]
    say_run_notes(vehicle, car, source, run, spikes, messages)
    return Check(report, messages.of("warning"), messages)
