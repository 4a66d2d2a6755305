"""What the workflows derive from a finished estimate or fit: the handling metrics with σ
(:mod:`online_id.handling`), from the parameters and their covariance, at the run's median speed, with the
run's own yaw-rate/steering response beside them.

A failure here is never the end of the job: the parameters are the result, the metrics a reading of them;
it is absorbed (counted in the crash report's session, :mod:`online_id.util.stages`) and said in a warning.
"""

from __future__ import annotations

import numpy as np

from online_id.util import stages
from online_id.workflows.messages import Messages


def handling_of(parameters, covariance, vehicle, *, run=None, speed_mps: float | None = None,
                messages: Messages | None = None):
    """The :class:`~online_id.handling.Handling` of ``parameters`` (a Parameters) with σ from ``covariance``
    (8, 8) [SI] for ``vehicle``, at ``speed_mps`` (default: the median speed of ``run``, a TrackRun whose
    response is measured too), or None with a warning when it cannot be computed."""
    from online_id.handling import handling

    try:
        with stages.stage("handling metrics"):
            if speed_mps is None:
                speed_mps = float(np.median(run.speed)) if run is not None else float("nan")
            return handling(parameters.to_vector(), covariance, vehicle.known, speed_mps, run=run)
    except Exception as exc:  # a reading of the result: it must not cost the result
        line = stages.absorb(exc, "handling metrics")
        if messages is not None:
            messages.warning(f"handling metrics not computed: {line}")
        return None
