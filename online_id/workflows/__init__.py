"""One function per job, taking plain arguments and returning a result object: the only path from a
front end into the core.

=============  ========================================================  ==================
job            function                                                  returns
=============  ========================================================  ==================
estimate       :func:`online_id.workflows.estimate_job.estimate`         :class:`Estimate`
fit            :func:`online_id.workflows.fit_job.fit`                   :class:`Fit`
diagnose       :func:`online_id.workflows.diagnose_job.diagnose`         :class:`Diagnosis`
check          :func:`online_id.workflows.check_job.check`               :class:`Check`
listen         :func:`online_id.workflows.listen_job.listen`             :class:`Listening`
convergence    :func:`online_id.workflows.convergence_job.convergence`   :class:`Convergence`
report         :func:`online_id.workflows.report_job.report`             :class:`Report`
=============  ========================================================  ==================

The CLI (:mod:`online_id.cli`: parses, prints, writes files), the Python API (:mod:`online_id.api`)
and ``batch`` (:mod:`online_id.batch`) call only these, so a flag added here reaches every front end.
A workflow never prints: what it has to say goes to a :class:`~online_id.workflows.messages.Messages`
(the CLI's prints each line as it comes) and onto the result. Inputs are resolved in
:mod:`online_id.workflows.inputs`. A new job is a module here (``<job>_job.py``: the function keeps
the job's name and the module does not, so ``online_id.workflows.estimate`` is only ever the function)
plus a thin command in ``online_id/cli/``.

The names load on first use (PEP 562): ``import online_id.workflows`` costs nothing.
"""

from __future__ import annotations

from importlib import import_module

#: name -> module of this package that defines it
_WHERE = {
    **{job: f"{job}_job" for job in ("estimate", "fit", "diagnose", "check", "listen", "convergence", "report")},
    "Messages": "messages",
    **{n: "results" for n in ("Estimate", "Fit", "Diagnosis", "Check", "Listening", "Convergence", "Report",
                                "Value")},
}


def __getattr__(name: str):
    if name in _WHERE:
        return getattr(import_module(f"online_id.workflows.{_WHERE[name]}"), name)
    raise AttributeError(f"module 'online_id.workflows' has no attribute {name!r}")


def __dir__():
    return sorted([*globals(), *_WHERE])


__all__ = list(_WHERE)
