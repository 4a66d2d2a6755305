"""The inputs every workflow resolves the same way: vehicle, prior, fixed parameters, effects, the
filter's settings, and the run itself (a path in any format, a DataFrame, a TrackRun, or the built-in
run). Front ends pass plain values (a vehicle name, a path, ``["Mzz=1600"]``); the workflows get
objects back, with one-line :class:`~online_id.errors.OnlineIdError` for anything wrong.

``drivers`` (the sources) is imported inside the functions: the core stays free of it, and a command
that never opens a log never pays for it.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping
from dataclasses import replace
from pathlib import Path

import numpy as np

from online_id.errors import OnlineIdError
from online_id.io.tracklog import TrackRun, lateral_velocity_at_cg
from online_id.util.stages import stage
from online_id.vehicle.loader import Vehicle, builtin_vehicle_names, load_vehicle
from online_id.vehicle.parameters import PARAMETER_NAMES, PARAMETER_UNITS, Parameters
from online_id.workflows.messages import Messages

#: What the built-in run is (``online-id estimate`` with no LOG).
BUILTIN_RUN = "Haro's 0.2-4 Hz chirp, 22 deg, 80 km/h, 60 s at 1 kHz, Table 6 car, seed 0"


#: The car a run is estimated as when no vehicle is given: Haro's test car (MODEL.md).
DEFAULT_VEHICLE = "haro2008"


def vehicle_of(vehicle) -> Vehicle:
    """A :class:`Vehicle` from a built-in name, a TOML path, or a Vehicle; None: :data:`DEFAULT_VEHICLE` (say
    so with :func:`say_default_vehicle` once the run is known)."""
    if vehicle is None:
        vehicle = DEFAULT_VEHICLE
    return vehicle if isinstance(vehicle, Vehicle) else load_vehicle(str(vehicle))


def say_default_vehicle(given, car: Vehicle, source, run: TrackRun | None, messages: Messages) -> None:
    """Warn when no vehicle was ``given`` (None) for a log (``source`` not None: not the built-in run) that was
    not made with the default car (``run``'s truth sidecar names the vehicle: ``simulate``'s runs do): its known
    constants (mass, axle positions, steering ratio, roll geometry) shape every value, the handling metrics most
    of all, and a real car was estimated as Haro's test car without a word (issue 39). Said once the job has its
    result, so that a log refused stays one error line."""
    if given is not None or source is None or (getattr(run, "meta", None) or {}).get("vehicle") == car.name:
        return
    label = getattr(run, "source", None) or str(source)
    k = car.known
    messages.warning(f"no --vehicle: {label} is estimated as {car.name}, the default car"
                     f" (M {k.M:g} kg, l1 {k.l1:g} m, l2 {k.l2:g} m, steering ratio {k.steering_ratio:g}): its"
                     " constants shape every value and every handling metric; pass --vehicle NAME or a TOML file"
                     " for this car (built-in: " + ", ".join(builtin_vehicle_names()) + ")")


# -- the prior ---------------------------------------------------------------------------------------------

def read_prior(path: Path) -> tuple[Parameters, np.ndarray]:
    """Values and relative 1σ from a JSON with ``{"parameters": {"Mzz": {"value": v, "std": s}, ...}}``.

    A ``null`` std (a parameter the fit could not determine) gives NaN: the estimator then uses
    the vehicle's prior σ for it.
    """
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise OnlineIdError(f"{path}: no such prior file") from None
    except (OSError, ValueError) as exc:
        raise OnlineIdError(f"{path}: not a readable JSON prior: {exc}") from None
    params = data.get("parameters") if isinstance(data, dict) else None
    if not isinstance(params, dict):
        raise OnlineIdError(f"{path}: missing key 'parameters'")
    values, rel = [], []
    for n in PARAMETER_NAMES:
        entry = params.get(n)
        if not isinstance(entry, dict) or "value" not in entry or "std" not in entry:
            raise OnlineIdError(f"{path}: missing key parameters.{n} with 'value' and 'std'")
        v, s = entry["value"], entry["std"]
        if not (isinstance(v, (int, float)) and v > 0 and (s is None or isinstance(s, (int, float)) and s > 0)):
            raise OnlineIdError(f"{path}: parameters.{n}: value and std must be positive numbers, got {v!r}, {s!r}")
        values.append(float(v))
        rel.append(np.nan if s is None else float(s) / float(v))
    return Parameters.from_vector(values), np.array(rel)


def prior_of(prior) -> tuple[Parameters | None, np.ndarray | None]:
    """(values, relative σ) from a fit or estimate JSON path, or a result with ``parameters`` and ``std``
    (an :class:`~online_id.workflows.results.Estimate` or ``Fit``, or their inner results); (None, None)."""
    if prior is None:
        return None, None
    if isinstance(prior, (str, Path)):
        return read_prior(Path(prior))
    inner = getattr(prior, "result", prior)
    if hasattr(inner, "parameters") and hasattr(inner, "std"):
        values = inner.parameters.to_vector()
        rel = np.where(np.isfinite(inner.std), np.asarray(inner.std, dtype=float) / values, np.nan)
        return inner.parameters, rel
    raise OnlineIdError(f"prior: a fit JSON path, a Fit or an Estimate, not {type(prior).__name__}")


def parse_fix(items: Iterable[str] | Mapping[str, float] | None, prior: Parameters) -> dict[str, float]:
    """``["Mzz=1600", "b1"]`` (``--fix``) or ``{"Mzz": 1600}`` → ``{"Mzz": 1600.0, "b1": <prior b1>}``;
    bad input is an :class:`OnlineIdError`."""
    if not items:
        return {}
    if isinstance(items, Mapping):
        items = [f"{k}={v}" for k, v in items.items()]
    fixed: dict[str, float] = {}
    for item in items:
        name, sep, text = (part.strip() for part in str(item).partition("="))
        if name not in PARAMETER_NAMES:
            raise OnlineIdError(f"--fix {item}: unknown parameter {name!r}; choose from {', '.join(PARAMETER_NAMES)}")
        if name in fixed:
            raise OnlineIdError(f"--fix {item}: {name} is fixed twice")
        if not sep:
            fixed[name] = float(getattr(prior, name))
            continue
        try:
            value = float(text)
        except ValueError:
            raise OnlineIdError(f"--fix {item}: {text!r} is not a number (SI units: {PARAMETER_UNITS[name]})") from None
        if not (math.isfinite(value) and value > 0):
            raise OnlineIdError(f"--fix {item}: the value must be positive and finite ({PARAMETER_UNITS[name]})")
        fixed[name] = value
    if len(fixed) == len(PARAMETER_NAMES):
        raise OnlineIdError("--fix: every parameter is fixed; nothing left to estimate")
    return fixed


# -- effects and offsets -----------------------------------------------------------------------------------

def effects_of(effects=(), effects_from=None, *, online: bool, messages: Messages | None = None) -> list:
    """Effects from ``NAME[:CHANNEL][:START]`` strings (``--effect``) or instances, and those a diagnosis
    named (``--effects-from``: a ``diagnose --json`` path, or a Diagnosis); one given explicitly wins over the
    diagnosis's of the same label. ``online``: only the diagnosis's effects with a filter form (the others
    are named in a warning)."""
    from online_id.effects import parse_effect_to_estimate

    given = [parse_effect_to_estimate(e) if isinstance(e, str) else e for e in effects or ()]
    if effects_from is None:
        return given
    warn = messages.warning if messages is not None else (lambda line: None)
    carry = getattr(getattr(effects_from, "result", None), "carry", None)
    if carry is not None or hasattr(effects_from, "result"):  # a Diagnosis (the API's or the workflow's)
        carry = carry or {}
        named = [parse_effect_to_estimate(s) for s in carry.get("online" if online else "fit", [])]
    else:
        from online_id.diagnosis.carry import effects_from_diagnosis

        named = effects_from_diagnosis(effects_from, online, warn=warn)
    labels = {e.label for e in given}
    return given + [e for e in named if e.label not in labels]


def filter_effects_of(effects, effects_from, known, messages: Messages | None = None) -> list:
    """The effects to estimate online, checked up front to have a filter form and to be asked for once (a
    one-line OnlineIdError before any data is read, so no data warning precedes it)."""
    from online_id.filters.augment import Augmentation

    chosen = effects_of(effects, effects_from, online=True, messages=messages)
    Augmentation.from_effects(chosen, known)
    return chosen


def check_effects_act(effects, channels, source: str) -> None:
    """A one-line OnlineIdError for an effect with nothing to act on among the run's measured ``channels`` (a
    lateral-velocity sensor's misalignment on a run without that channel: its estimate would be the prior's, said
    nowhere)."""
    channels = tuple(channels)
    for e in effects:
        if not type(e).candidates(channels):
            raise OnlineIdError(f"--effect {e.name}: {source} has nothing for it to act on (its channels:"
                                f" {', '.join(channels)})")


def offset_channels(offsets: bool, channels: Iterable[str]) -> list[str] | bool:
    """The offset channels ``--offsets`` asks for, among the measured ``channels`` (the steering is always
    there); False without."""
    if not offsets:
        return False
    from online_id.effects import OFFSET_CHANNELS

    channels = set(channels)
    return [c for c in OFFSET_CHANNELS if c in channels or c == "steering_wheel_angle"]


# -- the filter's settings ---------------------------------------------------------------------------------

def intersample_of(intersample: str | None) -> str:
    """The steering between samples every job's model takes (``--intersample``, :mod:`online_id.model.intersample`):
    as asked, or the filters' default (:attr:`~online_id.filters.FilterConfig.intersample`): one setting for the
    filters, the polish, the fit, the diagnosis and the checks; an unknown kind is an OnlineIdError."""
    from online_id.filters.config import FilterConfig
    from online_id.model.intersample import check_kind

    if intersample is None:
        return FilterConfig().intersample
    try:
        return check_kind(str(intersample))
    except ValueError as exc:
        raise OnlineIdError(f"--intersample: {exc}") from None


def filter_config(correct_every: int | None = None, keep_prior_std: bool = False, channels=None,
                  intersample: str | None = None):
    """The :class:`~online_id.filters.FilterConfig` asked for: ``correct_every`` (``--correct-every``),
    ``keep_prior_std`` (``--keep-prior-std``: no widening of the prior's σ), the measured ``channels``
    used (the others get no measurement noise entry: they are not configured at all), and ``intersample``
    (``--intersample``; None: the default)."""
    from online_id.filters import FilterConfig

    config = FilterConfig()
    if intersample is not None:
        config = replace(config, intersample=intersample_of(intersample))
    if correct_every is not None:
        if int(correct_every) < 1:
            raise OnlineIdError("--correct-every must be at least 1")
        config = replace(config, correct_every=int(correct_every))
    if keep_prior_std:
        config = replace(config, prior_log_std_floor=0.0)
    if channels is not None:
        config = replace(config, measurement_std={c: v for c, v in config.measurement_std.items() if c in channels})
    return config


# -- the run -----------------------------------------------------------------------------------------------

def source_options(dbc=None, signals=None, can_channel=None, drop_nan: bool = False) -> dict:
    """Keywords for ``online_id.drivers.sources.open_source`` / ``load_run``."""
    return {"dbc": dbc, "signals": signals, "can_channel": can_channel, "drop_nan": bool(drop_nan)}


def builtin_run(vehicle: Vehicle, messages: Messages | None = None) -> TrackRun:
    """The built-in simulated run (:data:`BUILTIN_RUN`) of ``vehicle``'s ``track`` truth."""
    from online_id.sim.simulator import simulate

    if messages is not None:
        messages.status(f"no LOG given: using the built-in run ({BUILTIN_RUN})")
    if vehicle.name != "haro2008" and "track" not in vehicle.truths:
        raise OnlineIdError(f"the built-in run needs a [truth.track] set in {vehicle.source}")
    run = simulate(vehicle, vehicle.truth("track"), truth_name="track", seed=0).run
    run.source = "the built-in run"
    return run


def is_source_object(source) -> bool:
    """True for what is not a path: a TrackRun or a pandas DataFrame."""
    return isinstance(source, TrackRun) or (hasattr(source, "columns") and hasattr(source, "__len__"))


def input_source(source, dbc=None, signals=None, can_channel=None, drop_nan: bool = False):
    """A ``drivers`` SampleSource for a path, a pandas DataFrame or a TrackRun."""
    from online_id.drivers.csv_source import TrackRunSource
    from online_id.drivers.sources import open_source as open_path
    from online_id.drivers.sources import run_from_dataframe

    if isinstance(source, TrackRun):
        return TrackRunSource(run=source)
    if isinstance(source, (str, Path)):
        return open_path(source, **source_options(dbc, signals, can_channel, drop_nan))
    if hasattr(source, "columns") and hasattr(source, "__len__"):  # a pandas DataFrame
        return TrackRunSource(run=run_from_dataframe(source))
    raise OnlineIdError(f"source: a path, a pandas DataFrame or a TrackRun, not {type(source).__name__}")


@stage("reading the log")
def input_run(source, vehicle: Vehicle, *, dbc=None, signals=None, can_channel=None, resample: float | None = None,
             messages: Messages | None = None, drop_nan: bool = False) -> tuple[TrackRun, list[str]]:
    """The whole run of ``source`` (any path ``online_id.drivers.sources`` reads, a DataFrame, a TrackRun; the built-in
    run when None), decoded and resampled as asked, with the problems its source and decoding saw (also
    reported as warnings to ``messages``, with the sampling's)."""
    messages = messages if messages is not None else Messages()
    if source is None:
        return builtin_run(vehicle, messages), []
    if is_source_object(source):
        src = input_source(source)
        say_unused_columns(src.run, messages)
        return lateral_velocity_at_cg(src.run, vehicle.sensor_position("lateral_velocity_x_m")), []
    from online_id.drivers.sources import load_run as load_any

    loaded = load_any(source, **source_options(dbc, signals, can_channel, drop_nan))
    run, problems = loaded.run, loaded.reading_notes()  # a table: columns mapped, rows dropped
    if loaded.decode is not None:  # a log decoded into a run: what the source and the decoding saw
        problems = loaded.problems()
        messages.status(f"{source}: decoded {len(run)} samples ({', '.join(run.channels[1:])})")
    if resample:
        from online_id.drivers.resample import resample_run

        run, info = resample_run(run, resample)
        messages.status(f"{source}: resampled {info['samples_before']} samples to {info['samples']} at"
                        f" {resample:g} Hz (longest interval interpolated {1e3 * info['longest_interval_s']:.3g} ms)")
    for warning in problems + run.sampling.warnings():
        messages.warning(f"{source}: {warning}")
    say_unused_columns(run, messages)
    return lateral_velocity_at_cg(run, vehicle.sensor_position("lateral_velocity_x_m")), problems


def say_unused_columns(run: TrackRun, messages: Messages) -> None:
    """Say which of the run's columns the lateral model reads and does not use (none is ignored silently)."""
    ax = run.longitudinal_acceleration
    if ax is not None:
        from online_id.effects import EFFECTS

        laws = [name for name, cls in EFFECTS.items() if cls.moves_loads]
        messages.note(f"{run.source}: longitudinal_acceleration read ({ax.min():.3g} to {ax.max():.3g} m/s²): the"
                      f" axle loads of {', '.join(laws[:-1])} and {laws[-1]} follow it, and diagnose says where the"
                      " gap lies by it; the base model and the other effects do not use it")


def only_run_channels(run: TrackRun, channels) -> TrackRun:
    """``run`` with the measured channels outside ``channels`` (``"a,b"`` or a list, as ``--channels``; each one the
    run has) left out."""
    from dataclasses import replace

    from online_id.drivers.csv_source import TrackRunSource
    from online_id.drivers.sources import select_channels
    from online_id.stream.samples import MEASURED_CHANNELS

    chosen = select_channels(channels, TrackRunSource(run=run))
    return replace(run, **{c: None for c in MEASURED_CHANNELS if c not in chosen})


def mended(run: TrackRun):
    """``run`` with its single-sample input spikes mended (:mod:`online_id.trust.spikes`); returns (run, spikes),
    said with the result by :func:`say_run_notes`."""
    from online_id.trust.spikes import mend_run

    return mend_run(run)


def say_run_notes(given, car: Vehicle, source, run: TrackRun | None, spikes, messages: Messages) -> None:
    """What a job says about its input once it has its result (a log refused stays one error line): the
    input spikes mended and the default car (:func:`say_default_vehicle`)."""
    from online_id.trust.spikes import spike_lines

    where = getattr(run, "source", None) or (str(source) if source is not None else "")
    for line in spike_lines(spikes, f"{where}: " if where else ""):
        messages.warning(line)
    say_default_vehicle(given, car, source, run, messages)


def run_truth(run: TrackRun) -> Parameters | None:
    """The parameters a simulated run was made with (its truth sidecar), else None."""
    truth = run.truth
    if not truth:
        return None
    try:
        return Parameters(**{n: float(truth[n]) for n in PARAMETER_NAMES})
    except (KeyError, TypeError, ValueError):
        return None


def plausibility_of(run: TrackRun, vehicle: Vehicle, allow_implausible, messages: Messages):
    """Judge a whole run's inputs (online_id.trust.plausibility); raise ImplausibleInputError (exit 2) or
    report what was allowed as warnings. Returns the PlausibilityReport (for the JSON: what was allowed)."""
    from online_id.trust.plausibility import judge_run, parse_allow

    report = judge_run(run, vehicle)
    for line in report.enforce(parse_allow(allow_implausible)):
        messages.warning(line)
    return report
