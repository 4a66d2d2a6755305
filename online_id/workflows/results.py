"""What the workflows return: one result object per job, wrapping the core's result with what the run
reported. Every front end reads these: the CLI prints and writes them, the Python API hands them to a
notebook, ``batch`` stores their JSON.

Each has ``result`` (the core's own result object: :class:`~online_id.estimation.EstimationResult`,
:class:`~online_id.batchfit.fit.FitResult`, :class:`~online_id.diagnosis.diagnose.GapDiagnosis`, ...),
``warnings`` (about the input and the run, in order) and ``messages`` (every line the run reported,
:class:`~online_id.workflows.messages.Messages`), plus ``parameters`` as ``{name: Value(value, std)}``,
``to_json()`` (the JSON of the command's ``--json``) and, where a history exists, ``to_dataframe()``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from online_id.vehicle.parameters import PARAMETER_NAMES
from online_id.workflows.messages import Messages


class Value(NamedTuple):
    """One parameter's value and 1σ [SI units]; σ is None where the data could not determine it."""

    value: float
    std: float | None


def _values(values, stds) -> dict[str, Value]:
    return {n: Value(float(v), float(s) if s is not None and np.isfinite(s) else None)
            for n, v, s in zip(PARAMETER_NAMES, values, stds)}


def _json(data: dict, path: str | Path | None) -> str:
    from online_id.util.jsonio import json_text

    text = json_text(data)
    if path is not None:
        Path(path).write_text(text, encoding="utf-8")
    return text


@dataclass
class _Result:
    result: Any
    warnings: list[str] = field(default_factory=list)
    messages: Messages = field(default_factory=Messages)

    @property
    def source_problems(self) -> list[str]:
        """The warnings (the name of the API's first release)."""
        return self.warnings

    def to_json_dict(self) -> dict:
        """The data of the command's ``--json`` (``to_json`` writes it)."""
        return self.result.to_json_dict()


@dataclass
class Estimate(_Result):
    """An online estimate (``online-id estimate``). ``result`` is the
    :class:`~online_id.estimation.EstimationResult`; ``notes`` say how the run was set up (a prior
    widened); ``label`` names the source in messages."""

    notes: list[str] = field(default_factory=list)
    label: str = ""

    @property
    def parameters(self) -> dict[str, Value]:
        """The estimate of each parameter by name (``"Mzz"``, ...): value and 1σ, SI units."""
        return _values(self.result.parameters.to_vector(), self.result.std)

    def to_dataframe(self):
        """The estimate's history: ``time`` [s], then ``<name>`` and ``<name>_std`` per parameter (SI)."""
        import pandas as pd

        tr = self.result.trace
        cols = {"time": tr.time}
        for i, n in enumerate(PARAMETER_NAMES):
            cols[n], cols[f"{n}_std"] = tr.values[:, i], tr.std[:, i]
        return pd.DataFrame(cols)

    def to_json(self, path: str | Path | None = None) -> str:
        """The JSON of ``online-id estimate --json`` (written to ``path`` when given)."""
        return _json(self.result.to_json_dict(), path)

    def __repr__(self) -> str:
        return f"Estimate({self.result.filter}, {self.result.samples} samples)\n{self.result.table()}"


@dataclass
class Fit(_Result):
    """A batch fit (``online-id fit``). ``result`` is the :class:`~online_id.batchfit.fit.FitResult`;
    ``handling`` the handling metrics of the fitted parameters with σ from the fit's covariance
    (:class:`~online_id.handling.Handling`, the ``handling`` key of ``fit --json``; None when not computed)."""

    handling: Any = None

    def to_json_dict(self) -> dict:
        """The data of ``online-id fit --json``: the fit's own keys and ``handling``."""
        out = self.result.to_json_dict()
        if self.handling is not None:
            out["handling"] = self.handling.to_json_dict()
        return out

    @property
    def parameters(self) -> dict[str, Value]:
        """The fitted value of each parameter by name and its 1σ (None where not determined), SI units."""
        return _values(self.result.parameters.to_vector(), self.result.std)

    def to_dataframe(self):
        """The history of the search: ``generation`` and the GA's best ``cost`` (eq 12) after it."""
        import pandas as pd

        hist = self.result.ga.history
        return pd.DataFrame({"generation": np.arange(1, len(hist) + 1), "cost": np.asarray(hist, dtype=float)})

    def to_json(self, path: str | Path | None = None) -> str:
        """The JSON of ``online-id fit --json``: a prior for ``estimate(prior=...)``."""
        return _json(self.to_json_dict(), path)

    def __repr__(self) -> str:
        return f"Fit({self.result.evaluations} evaluations)\n{self.result.table()}"


@dataclass
class Diagnosis(_Result):
    """A sim-to-real gap diagnosis (``online-id diagnose``). ``result`` is the
    :class:`~online_id.diagnosis.diagnose.GapDiagnosis`."""

    @property
    def parameters(self) -> dict[str, Value]:
        """The base model's fitted parameters (σ not estimated by the diagnosis: None)."""
        return _values(self.result.base.theta, [None] * len(PARAMETER_NAMES))

    @property
    def verdict(self) -> str | None:
        """The effect that explains the gap best (significant, lowest held-out cost), or None."""
        return self.result.verdict

    def to_dataframe(self):
        """One row per candidate effect, best first: held-out cost before and after, reduction, significance."""
        import pandas as pd

        rows = self.result.to_json_dict()["effects"]
        return pd.DataFrame([{k: v for k, v in r.items() if not isinstance(v, (dict, list))} for r in rows])

    def to_json(self, path: str | Path | None = None) -> str:
        """The JSON of ``online-id diagnose --json``."""
        return _json(self.result.to_json_dict(), path)


@dataclass
class Check(_Result):
    """What a run can tell (``online-id check``). ``result`` is the :class:`~online_id.trust.check.CheckReport`."""

    def to_json(self, path: str | Path | None = None) -> str:
        """The JSON of ``online-id check --json``."""
        return _json(self.result.to_json_dict(), path)

    def __repr__(self) -> str:
        return self.result.text()


@dataclass
class Convergence(_Result):
    """Runs of one filter from several initial covariances and values (``online-id plot convergence``).
    ``result`` is the list of ``(label, EstimationResult)``; ``truth`` the run's truth when known."""

    truth: Any = None
    channels: list[str] = field(default_factory=list)
    source: str = ""

    @property
    def interrupted(self) -> bool:
        """True when a run was interrupted (the runs after it were not made)."""
        return any(r.interrupted for _, r in self.result)


@dataclass
class Listening(_Result):
    """A live estimate from a bus (``online-id listen``). ``result`` is the
    :class:`~online_id.estimation.EstimationResult`; ``loss`` the frame and sample loss (the top-level keys
    of ``listen --json``); ``ended_by`` why the stream ended; ``nothing_arrived`` when no frame came before
    the start timeout."""

    name: str = ""
    loss: dict = field(default_factory=dict)
    ended_by: str | None = None
    nothing_arrived: bool = False
    frames: int = 0
    samples_made: int = 0

    @property
    def parameters(self) -> dict[str, Value]:
        """The live estimate of each parameter by name: value and 1σ, SI units."""
        return _values(self.result.parameters.to_vector(), self.result.std)

    def to_json(self, path: str | Path | None = None) -> str:
        """The JSON of ``online-id listen --json``."""
        return _json(dict(self.result.to_json_dict(), **self.loss), path)


@dataclass
class Report(_Result):
    """Every job over one run, for one page (``online-id report``). ``result`` is unused (None); the parts
    are ``check``, ``estimate``, ``fit``, ``diagnosis`` (each the job's own result, None when switched off
    or failed: ``errors[part]`` then says why), ``agreement`` (the estimate against the fit, z per
    parameter, as ``estimate --prior``'s cross-check), ``excitation`` and ``learned``
    (:class:`~online_id.trust.over_time.Excitation`: the run's Fisher information and what the filter
    gained, window by window), ``innovations`` (per channel, :class:`~online_id.trust.over_time.InnovationWindows`),
    ``run`` (the TrackRun, for its channels), ``commands`` (the command line of each part)."""

    source: str = ""
    vehicle: str = ""
    run: Any = None
    check: Check | None = None
    estimate: Estimate | None = None
    fit: Fit | None = None
    diagnosis: Diagnosis | None = None
    agreement: dict | None = None
    excitation: Any = None
    learned: Any = None
    innovations: list = field(default_factory=list)
    commands: dict = field(default_factory=dict)
    skipped: list[str] = field(default_factory=list)
    errors: dict[str, str] = field(default_factory=dict)
    wall_s: dict[str, float] = field(default_factory=dict)
    #: the part during which the run was interrupted (the parts after it were not made), else None
    interrupted: str | None = None

    @property
    def parameters(self) -> dict[str, Value]:
        """The estimate of each parameter by name: value and 1σ, SI units."""
        return self.estimate.parameters

    def to_json(self, path: str | Path | None = None) -> str:
        """Each part's JSON (as its own command's ``--json``) under its name, with the agreement, the
        commands, the excitation meters, the parts skipped or failed and their wall times."""
        data = {"source": self.source, "vehicle": self.vehicle, "commands": self.commands,
                "skipped": self.skipped, "errors": self.errors, "wall_s": self.wall_s,
                "interrupted": self.interrupted}
        for name, part in (("check", self.check), ("estimate", self.estimate), ("fit", self.fit),
                           ("diagnose", self.diagnosis)):
            if part is not None:
                data[name] = part.to_json_dict()
        if self.agreement is not None:
            data["agreement"] = self.agreement
        for name, meter in (("excitation", self.excitation), ("learned", self.learned)):
            if meter is not None:
                data[name] = meter.to_json_dict()
        return _json(data, path)
