"""The Python API for notebooks: ``online_id.estimate``, ``online_id.fit``, ``online_id.diagnose``.

::

    import online_id
    est = online_id.estimate("run.csv", vehicle="haro2008", filter="ekf")
    est.parameters["Mzz"].value, est.parameters["Mzz"].std   # SI units
    est.to_dataframe()                                       # the history: time, Mzz, Mzz_std, ...
    est.to_json("est.json")                                  # the JSON of `online-id estimate --json`

``source`` is a path in any format the CLI reads (track-run CSV or parquet, CAN logs in every
python-can format with ``dbc=``/``signals=``/``can_channel=``, MDF files), a pandas DataFrame with
the track-run columns (SI units: see ``online_id.io.tracklog``), or a ``TrackRun``. The same code as
the CLI runs, so the numbers are the CLI's. A front end, like ``online_id.cli``: it imports
``drivers`` (and pandas) only inside the functions, so ``import online_id`` stays cheap.
"""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from online_id.errors import OnlineIdError
from online_id.io.tracklog import TrackRun
from online_id.vehicle.parameters import PARAMETER_NAMES


class Value(NamedTuple):
    """One parameter's value and 1σ [SI units]; σ is None where the data could not determine it."""

    value: float
    std: float | None


def _values(values, stds) -> dict[str, Value]:
    return {n: Value(float(v), float(s) if s is not None and np.isfinite(s) else None)
            for n, v, s in zip(PARAMETER_NAMES, values, stds)}


def _json(data: dict, path: str | Path | None) -> str:
    text = json.dumps(data, indent=2, allow_nan=False, default=_jsonable) + "\n"
    if path is not None:
        Path(path).write_text(text, encoding="utf-8")
    return text


def _jsonable(x):
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    raise TypeError(f"not JSON serialisable: {type(x)}")


@dataclass
class Estimate:
    """An online estimate. ``result`` is the full :class:`online_id.estimation.EstimationResult`."""

    result: Any
    source_problems: list[str]

    @property
    def parameters(self) -> dict[str, Value]:
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
class Fit:
    """A batch fit. ``result`` is the full :class:`online_id.batchfit.fit.FitResult`."""

    result: Any
    source_problems: list[str]

    @property
    def parameters(self) -> dict[str, Value]:
        return _values(self.result.parameters.to_vector(), self.result.std)

    def to_dataframe(self):
        """The history of the search: ``generation`` and the GA's best ``cost`` (eq 12) after it."""
        import pandas as pd

        hist = self.result.ga.history
        return pd.DataFrame({"generation": np.arange(1, len(hist) + 1), "cost": np.asarray(hist, dtype=float)})

    def to_json(self, path: str | Path | None = None) -> str:
        """The JSON of ``online-id fit --json``: a prior for ``estimate(prior=...)``."""
        return _json(self.result.to_json_dict(), path)

    def __repr__(self) -> str:
        return f"Fit({self.result.evaluations} evaluations)\n{self.result.table()}"


@dataclass
class Diagnosis:
    """A sim-to-real gap diagnosis. ``result`` is the full :class:`online_id.diagnosis.diagnose.Diagnosis`."""

    result: Any
    source_problems: list[str]

    @property
    def parameters(self) -> dict[str, Value]:
        """The base model's fitted parameters (σ not estimated by the diagnosis: None)."""
        return _values(self.result.base.theta, [None] * len(PARAMETER_NAMES))

    @property
    def verdict(self) -> str | None:
        return self.result.verdict

    def to_dataframe(self):
        """One row per candidate effect, best first: held-out cost before and after, reduction, significance."""
        import pandas as pd

        rows = self.result.to_json_dict()["effects"]
        return pd.DataFrame([{k: v for k, v in r.items() if not isinstance(v, (dict, list))} for r in rows])

    def to_json(self, path: str | Path | None = None) -> str:
        """The JSON of ``online-id diagnose --json``."""
        return _json(self.result.to_json_dict(), path)


# -- inputs ---------------------------------------------------------------------------------------------

def _vehicle(vehicle):
    from online_id.vehicle.loader import Vehicle, load_vehicle

    return vehicle if isinstance(vehicle, Vehicle) else load_vehicle(str(vehicle))


def _open(source, dbc, signals, can_channel):
    """(SampleSource, TrackRun or None) for a path, a DataFrame or a TrackRun."""
    from drivers.csv_source import TrackRunSource
    from drivers.sources import open_source, run_from_dataframe

    if isinstance(source, TrackRun):
        return TrackRunSource(run=source)
    if isinstance(source, (str, Path)):
        return open_source(source, dbc=dbc, signals=signals, can_channel=can_channel)
    if hasattr(source, "columns") and hasattr(source, "__len__"):  # a pandas DataFrame
        return TrackRunSource(run=run_from_dataframe(source))
    raise OnlineIdError(f"source: a path, a pandas DataFrame or a TrackRun, not {type(source).__name__}")


def _run(source, dbc, signals, can_channel) -> tuple[TrackRun, list[str]]:
    """A TrackRun (decoded when the source is a log) and what the source reported."""
    from drivers.sources import run_from_samples

    src = _open(source, dbc, signals, can_channel)
    run = getattr(src, "run", None)
    if run is not None:
        return run, src.problems()
    with src:
        run, report = run_from_samples(src, src.name, src.channels)
    return run, src.problems() + report.problems()


def _prior(prior):
    """(Parameters, relative σ) from a fit JSON path, a :class:`Fit` or an :class:`Estimate`; (None, None)."""
    if prior is None:
        return None, None
    if isinstance(prior, (str, Path)):
        from online_id.cli.common import read_prior

        return read_prior(Path(prior))
    if isinstance(prior, (Fit, Estimate)):
        r = prior.result
        rel = np.where(np.isfinite(r.std), r.std / r.parameters.to_vector(), np.nan)
        return r.parameters, rel
    raise OnlineIdError(f"prior: a fit JSON path, a Fit or an Estimate, not {type(prior).__name__}")


def _truth(run: TrackRun):
    from online_id.cli.common import run_truth

    return run_truth(run)


# -- the three functions -----------------------------------------------------------------------------------

def estimate(source, *, vehicle="haro2008", filter: str = "ekf", prior=None, channels=None,
             correct_every: int | None = None, dbc=None, signals=None, can_channel=None,
             progress: bool = False, polish: bool | None = None, fixed: dict[str, float] | None = None,
             effects=(), offsets: bool = False, allow_implausible: str | None = None,
             effects_from=None) -> Estimate:
    """Online estimate of the 8 parameters (``online-id estimate``).

    source : path, pandas DataFrame (track-run columns, SI) or TrackRun
    vehicle : built-in name or TOML path (or a loaded Vehicle)
    filter : ``"ekf"`` or ``"ukf"``
    prior : fit JSON path, or a :class:`Fit` / :class:`Estimate` to start from
    channels : measured channels to use, e.g. ``["yaw_rate", "lateral_acceleration"]`` (default: all present)
    correct_every : correct every k-th sample (default: the filter's 20)
    dbc, signals, can_channel : how to decode a CAN log (default: online-id's own frames)
    polish : batch-polish the filter's estimate over the whole run (default, as ``online-id estimate``: on
        for a whole track run, with its effects, unless offsets or fixed parameters are asked for; off for a
        streamed CAN log)
    fixed : {name: value [SI]} held fixed (``--fix``)
    effects : effect names of the registry with their filter form, e.g. ``["accelerometer_gravity"]``
        (``--effect``), or ``NAME[:CHANNEL][:START]`` strings; offsets : estimate the sensor offsets too (``--offsets``)
    effects_from : a ``diagnose --json`` file (or :class:`Diagnosis`): the effects it named that the filters
        carry, from its fitted values (``--effects-from``)
    allow_implausible : plausibility checks to accept, e.g. ``"yaw_sign"`` or ``"all"`` (``--allow-implausible``)

    The consistency verdict is ``result.result.consistency`` (``"consistency"`` in ``to_json()``).
    """
    from drivers.sources import only_channels, record_source, select_channels
    from online_id.effects import OFFSET_CHANNELS
    from online_id.estimation import make_estimator, run_estimator
    from online_id.filters import FilterConfig
    from online_id.trust.plausibility import StreamChecker, judge_run, parse_allow

    car = _vehicle(vehicle)
    prior_values, prior_rel = _prior(prior)
    src = _open(source, dbc, signals, can_channel)
    chosen = select_channels(channels, src)
    config = FilterConfig()
    if correct_every is not None:
        config = replace(config, correct_every=int(correct_every))
    if channels is not None:
        config = replace(config, measurement_std={c: v for c, v in config.measurement_std.items() if c in chosen})
    effect_list = _effects(effects, effects_from, car, online=True)
    offset_channels = ([c for c in OFFSET_CHANNELS if c in chosen or c == "steering_wheel_angle"]
                       if offsets else False)
    estimator = make_estimator(car, filter, prior=prior_values, prior_relative_std=prior_rel, config=config,
                               fixed=fixed, effects=effect_list, offsets=offset_channels, channels=chosen)
    run = getattr(src, "run", None)
    extended = bool(fixed or offsets)
    if polish and (run is None or extended):
        raise OnlineIdError("polish=True needs a whole track run estimated without fixed parameters or offsets"
                            " (not a CAN log)")
    polish = polish if polish is not None else (run is not None and not extended)
    allow = parse_allow(allow_implausible)
    notes: list[str] = []
    samples = src if chosen == src.channels else only_channels(src, chosen)
    if run is not None:
        notes += judge_run(run, car).enforce(allow)
    else:
        samples = StreamChecker(car.known, car.prior, allow=allow, max_window_s=None, source=src.name,
                                on_notes=notes.extend).check(samples)
    with src:
        result = run_estimator(estimator, samples, total=len(run) if run is not None else None, progress=progress,
                               source=src.name, truth=_truth(run) if run is not None else None, channels=chosen)
    warnings_ = notes + record_source(result, src, chosen)
    if polish and not result.interrupted:
        from online_id.batchfit.polish import POLISH_BURN_IN_S, polish_estimate

        problem = polish_estimate(result, car, run, config.measurement_std, burn_in_s=POLISH_BURN_IN_S,
                                  prior_log_std_floor=config.prior_log_std_floor, effects=effect_list)
        if problem:
            warnings_.append(problem)
    return Estimate(result, warnings_)


def _effects(effects, effects_from, car, online: bool) -> list:
    """Effects from ``NAME[:CHANNEL][:START]`` strings or instances, and those a diagnosis named (a file or a
    :class:`Diagnosis`); one given explicitly wins over the diagnosis's of the same label."""
    from online_id.diagnosis.carry import effects_from_diagnosis
    from online_id.effects import parse_effect_to_estimate

    given = [parse_effect_to_estimate(e) if isinstance(e, str) else e for e in effects]
    if effects_from is None:
        return given
    if isinstance(effects_from, Diagnosis):
        carry = effects_from.result.carry or {}
        named = [parse_effect_to_estimate(s) for s in carry.get("online" if online else "fit", [])]
    else:
        named = effects_from_diagnosis(effects_from, online, warn=lambda line: warnings.warn(line, stacklevel=3))
    labels = {e.label for e in given}
    return given + [e for e in named if e.label not in labels]


def fit(source, *, vehicle="haro2008", generations: int | None = None, groups: int | None = None,
        bounds: tuple[float, float] = (0.2, 5.0), seed: int = 0, dbc=None, signals=None, can_channel=None,
        progress: bool = False, effects=(), effects_from=None) -> Fit:
    """Batch fit with Haro's hybrid GA (``online-id fit``); ``bounds`` are factors of the prior; ``effects`` and
    ``effects_from`` as in :func:`estimate` (every effect a diagnosis named: the fit takes every block-mean form)."""
    from online_id.batchfit.fit import FitConfig, fit_run
    from online_id.batchfit.ga import GAConfig

    car = _vehicle(vehicle)
    low, high = bounds
    if not 0 < low < 1 < high:
        raise OnlineIdError(f"bounds must satisfy 0 < low < 1 < high, got {low:g} {high:g}")
    ga = GAConfig()
    ga = replace(ga, generations=generations or ga.generations, groups=groups or ga.groups)
    run, problems = _run(source, dbc, signals, can_channel)
    result = fit_run(car, run, FitConfig(lower_factor=low, upper_factor=high, ga=ga), seed=seed,
                     truth=_truth(run), progress=progress, effects=_effects(effects, effects_from, car, online=False))
    return Fit(result, problems)


def diagnose(source, *, vehicle="haro2008", validate=None, effects: list[str] | None = None, dbc=None,
             signals=None, can_channel=None) -> Diagnosis:
    """The sim-to-real gap (``online-id diagnose``); ``validate`` is a second source to judge the fits on."""
    from online_id.diagnosis.diagnose import diagnose as run_diagnosis
    from online_id.effects import EFFECTS

    car = _vehicle(vehicle)
    unknown = [n for n in effects or [] if n not in EFFECTS]
    if unknown:
        raise OnlineIdError(f"effects: unknown {', '.join(unknown)}; choose from {', '.join(EFFECTS)}")
    run, problems = _run(source, dbc, signals, can_channel)
    held = None
    if validate is not None:
        held, more = _run(validate, dbc, signals, can_channel)
        problems += more
    return Diagnosis(run_diagnosis(car, run, held, effects=effects), problems)
