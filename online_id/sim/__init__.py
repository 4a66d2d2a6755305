"""Test manoeuvres (``maneuvers``) and the simulator that turns them into track runs (``simulator``)."""

#: The steering between samples (:mod:`online_id.model.intersample`) the batch jobs take when not told: the fit
#: (``FitConfig``, ``FitCost``), the polish, the diagnosis and the checks (Fisher information): the cubic, as the
#: filters' ``FilterConfig.intersample`` (which the workflows pass to every job). The simulators' own default
#: stays the hold: their plain form.
BATCH_INTERSAMPLE = "cubic"
