"""Vehicles described in TOML files, and the built-in ones shipped with the package.

A vehicle file has these tables (SI units; see ``data/haro2008.toml``)::

    name = "mycar"
    steering_ratio = 16.0              # optional, default 16
    [known]                            # every KnownParameters field but steering_ratio
    M = 1400.0
    ...
    [prior]                            # the 8 estimated parameters: Mzz Mxx D1 D2 Aro Kro b1 b2
    Mzz = 1571.0
    ...
    [prior_relative_std]               # optional; 1σ relative to the prior value, default 0.5
    Mzz = 0.20
    [truth.track]                      # optional named parameter sets for simulation
    Mzz = 634.6
    ...
    [sensors]                          # optional: where the sensors sit
    lateral_velocity_x_m = 0.0         # the lateral-velocity sensor (INS, optical) ahead of the CG [m]

Any missing key, unknown name or impossible value (a non-positive mass,
inertia, stiffness or length) is a :class:`~online_id.errors.VehicleFileError`
naming the file and the key.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field, fields
from importlib import resources
from pathlib import Path

from online_id.errors import VehicleFileError
from online_id.vehicle.parameters import OPTIONAL_KNOWN, PARAMETER_NAMES, KnownParameters, Parameters

DEFAULT_PRIOR_RELATIVE_STD = 0.5
DEFAULT_STEERING_RATIO = 16.0

#: Known parameters that must be strictly positive.
_POSITIVE_KNOWN = ("M", "ms", "h0", "l1", "l2", "hg", "steering_ratio")
#: Known parameters that may be zero but not negative.
_NON_NEGATIVE_KNOWN = ("Mxz", "h1", "h2")
#: The ``[sensors]`` table: each key a sensor's position [m], 0 when not given (issue 38). The lateral velocity
#: is moved to the centre of gravity with it: v_y,cg = v_y,s − x_s·r
#: (:func:`online_id.io.tracklog.lateral_velocity_at_cg`). A position further than MAX_SENSOR_OFFSET_M is refused.
MAX_SENSOR_OFFSET_M = 5.0
SENSOR_POSITIONS = {"lateral_velocity_x_m": "the lateral-velocity sensor's position ahead of the centre of gravity [m]"}


@dataclass(frozen=True)
class Vehicle:
    """A car: known constants, the prior on the 8 estimated parameters, and named truth sets.

    Attributes
    ----------
    name : short identifier
    known : the constants the model takes as given
    prior : prior (constructor) values of the 8 estimated parameters
    prior_relative_std : 1σ of the prior, relative to the value, per parameter
    truths : named parameter sets for simulation, e.g. ``"track"`` (Haro Table 6)
    source : where the description was read from
    sensors : the sensors' positions [m] (:data:`SENSOR_POSITIONS`; absent keys are 0)
    """

    name: str
    known: KnownParameters
    prior: Parameters
    prior_relative_std: Parameters
    truths: dict[str, Parameters] = field(default_factory=dict)
    description: str = ""
    source: str = ""
    sensors: dict[str, float] = field(default_factory=dict)

    def sensor_position(self, key: str) -> float:
        """A sensor's position from the ``[sensors]`` table [m] (0 when not given)."""
        return float(self.sensors.get(key, 0.0))

    def truth(self, key: str) -> Parameters:
        """A parameter set by name: ``"constructor"`` is the prior, other names come from ``[truth.*]``."""
        if key in ("constructor", "prior"):
            return self.prior
        try:
            return self.truths[key]
        except KeyError:
            available = ", ".join(["constructor", *self.truths])
            raise VehicleFileError(
                f"{self.source or self.name}: no parameter set named {key!r}; available: {available}"
            ) from None


def builtin_vehicle_names() -> list[str]:
    """Names of the vehicles shipped with the package."""
    data = resources.files("online_id.vehicle") / "data"
    return sorted(p.name[: -len(".toml")] for p in data.iterdir() if p.name.endswith(".toml"))


def load_vehicle(name_or_path: str | Path) -> Vehicle:
    """A built-in vehicle by name (``"haro2008"``) or a vehicle from a TOML file path."""
    text_name = str(name_or_path)
    if text_name in builtin_vehicle_names():
        resource = resources.files("online_id.vehicle") / "data" / f"{text_name}.toml"
        return parse_vehicle(resource.read_text(encoding="utf-8"), source=f"built-in vehicle {text_name!r}")
    path = Path(name_or_path)
    if not path.exists():
        raise VehicleFileError(
            f"{path}: no such vehicle file, and not a built-in vehicle (built-in: {', '.join(builtin_vehicle_names())})"
        )
    return parse_vehicle(path.read_text(encoding="utf-8"), source=str(path))


def parse_vehicle(text: str, source: str = "<string>") -> Vehicle:
    """Parse and validate a vehicle description given as TOML text."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise VehicleFileError(f"{source}: not valid TOML: {exc}") from None

    _reject_unknown(data, {"name", "description", "steering_ratio", "known", "prior", "prior_relative_std", "truth",
                           "sensors"}, source, "")
    name = data.get("name")
    if not isinstance(name, str) or not name:
        raise VehicleFileError(f"{source}: missing key 'name' (a non-empty string)")

    known_table = _table(data, "known", source, required=True)
    known_names = [f.name for f in fields(KnownParameters) if f.name != "steering_ratio"]
    _reject_unknown(known_table, set(known_names), source, "known.")
    known_values = {key: _number(known_table, key, source, "known.") for key in known_names
                    if key not in OPTIONAL_KNOWN or key in known_table}
    for key in OPTIONAL_KNOWN:
        if key in known_values and not 0.0 <= known_values[key] <= 1.0:
            raise VehicleFileError(f"{source}: known.{key} = {known_values[key]!r} must be a share from 0 to 1")
    known_values["steering_ratio"] = (
        _number(data, "steering_ratio", source, "") if "steering_ratio" in data else DEFAULT_STEERING_RATIO
    )
    for key in _POSITIVE_KNOWN:
        if known_values[key] <= 0:
            where = "steering_ratio" if key == "steering_ratio" else f"known.{key}"
            raise VehicleFileError(f"{source}: {where} = {known_values[key]!r} must be positive")
    for key in _NON_NEGATIVE_KNOWN:
        if known_values[key] < 0:
            raise VehicleFileError(f"{source}: known.{key} = {known_values[key]!r} must not be negative")
    if known_values["ms"] > known_values["M"]:
        raise VehicleFileError(
            f"{source}: known.ms = {known_values['ms']} kg exceeds the total mass known.M = {known_values['M']} kg"
        )

    prior = _parameter_set(_table(data, "prior", source, required=True), source, "prior.")
    std_table = _table(data, "prior_relative_std", source, required=False)
    _reject_unknown(std_table, set(PARAMETER_NAMES), source, "prior_relative_std.")
    stds = {}
    for key in PARAMETER_NAMES:
        stds[key] = _number(std_table, key, source, "prior_relative_std.") if key in std_table else (
            DEFAULT_PRIOR_RELATIVE_STD)
        if stds[key] <= 0:
            raise VehicleFileError(f"{source}: prior_relative_std.{key} = {stds[key]!r} must be positive")

    truths = {}
    truth_tables = _table(data, "truth", source, required=False)
    for set_name, table in truth_tables.items():
        if not isinstance(table, dict):
            raise VehicleFileError(f"{source}: truth.{set_name} must be a table of the 8 parameters")
        truths[set_name] = _parameter_set(table, source, f"truth.{set_name}.")

    sensor_table = _table(data, "sensors", source, required=False)
    _reject_unknown(sensor_table, set(SENSOR_POSITIONS), source, "sensors.")
    sensors = {key: _number(sensor_table, key, source, "sensors.") for key in sensor_table}
    for key, value in sensors.items():
        if abs(value) > MAX_SENSOR_OFFSET_M:
            raise VehicleFileError(f"{source}: sensors.{key} = {value!r} m is more than {MAX_SENSOR_OFFSET_M:g} m from"
                                   " the centre of gravity (a position in mm, or from the front axle?)")

    return Vehicle(
        name=name,
        sensors=sensors,
        known=KnownParameters(**known_values),
        prior=prior,
        prior_relative_std=Parameters(**stds),
        truths=truths,
        description=str(data.get("description", "")),
        source=source,
    )


def _table(data: dict, key: str, source: str, required: bool) -> dict:
    if key not in data:
        if required:
            raise VehicleFileError(f"{source}: missing table [{key}]")
        return {}
    if not isinstance(data[key], dict):
        raise VehicleFileError(f"{source}: {key} must be a table, got {type(data[key]).__name__}")
    return data[key]


def _reject_unknown(table: dict, allowed: set[str], source: str, prefix: str) -> None:
    unknown = sorted(set(table) - allowed)
    if unknown:
        raise VehicleFileError(
            f"{source}: unknown key {prefix}{unknown[0]}"
            f" (allowed in this table: {', '.join(sorted(allowed))})"
        )


def _number(table: dict, key: str, source: str, prefix: str) -> float:
    if key not in table:
        raise VehicleFileError(f"{source}: missing key {prefix}{key}")
    value = table[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise VehicleFileError(f"{source}: {prefix}{key} must be a number, got {value!r}")
    if not math.isfinite(value):
        raise VehicleFileError(f"{source}: {prefix}{key} = {value!r} is not finite")
    return float(value)


def _parameter_set(table: dict, source: str, prefix: str) -> Parameters:
    _reject_unknown(table, set(PARAMETER_NAMES), source, prefix)
    values = {key: _number(table, key, source, prefix) for key in PARAMETER_NAMES}
    for key, value in values.items():
        if value <= 0:
            raise VehicleFileError(f"{source}: {prefix}{key} = {value!r} must be positive")
    return Parameters(**values)
