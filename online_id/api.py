"""The Python API for notebooks: ``online_id.estimate``, ``online_id.fit``, ``online_id.diagnose``,
``online_id.check``.

::

    import online_id
    est = online_id.estimate("run.csv", vehicle="haro2008", filter="ekf")
    est.parameters["Mzz"].value, est.parameters["Mzz"].std   # SI units
    est.to_dataframe()                                       # the history: time, Mzz, Mzz_std, ...
    est.to_json("est.json")                                  # the JSON of `online-id estimate --json`
    est.warnings                                             # what the run said about its input

``source`` is a path in any format the CLI reads (track-run CSV or parquet, CAN logs in every
python-can format with ``dbc=``/``signals=``/``can_channel=``, MDF files), a pandas DataFrame with
the track-run columns (SI units: see ``online_id.io.tracklog``), a ``TrackRun``, or None for the
built-in run. These are the workflows of :mod:`online_id.workflows` themselves, which the CLI and
``batch`` call too: one path, so the numbers are the CLI's. ``import online_id`` stays cheap (the
names load on first use).
"""

from __future__ import annotations

from online_id.workflows.check_job import check
from online_id.workflows.diagnose_job import diagnose
from online_id.workflows.estimate_job import estimate
from online_id.workflows.fit_job import fit
from online_id.workflows.results import Check, Diagnosis, Estimate, Fit, Value

__all__ = ["Check", "Diagnosis", "Estimate", "Fit", "Value", "check", "diagnose", "estimate", "fit"]
