"""Test manoeuvres (``maneuvers``) and the simulator that turns them into track runs (``simulator``)."""

#: The steering between samples (:mod:`online_id.model.intersample`) the batch jobs take when not told: the fit
#: (``FitConfig``, ``FitCost``), the polish, the diagnosis and the checks (Fisher information). The hold, as before
#: issue 36, until it is switched with the filters' ``FilterConfig.intersample`` (which the workflows pass to every
#: job) and the simulator's ``INTEGRATION_RATE_HZ``. The simulators' own default stays the hold: their plain form.
BATCH_INTERSAMPLE = "hold"
