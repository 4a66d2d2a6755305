"""Candidate unmodelled effects: documented extensions of the base model with their own parameters.

Each module holds one effect (see :mod:`online_id.effects.base` for the contract: simulation,
block-mean and filter forms); :data:`EFFECTS` registers them by name for ``simulate --effect``,
``diagnose --effects``, and ``estimate``/``fit --effect``. The package imports no scipy (the CLI
builds its help from the registry at start-up): the model with effects over a whole run lives in
:mod:`online_id.sim.with_effects`.

Another package adds an effect without touching this one (python-can's ``can.interface`` entry points): an
:class:`Effect` subclass named in the entry-point group :data:`ENTRY_POINT_GROUP` of its ``pyproject.toml``,

    [project.entry-points."online_id.effects"]
    yaw_rate_scale = "my_package.gyro:YawRateScale"

joins :data:`EFFECTS` at import, with every command (``simulate``, ``estimate``, ``listen``, ``diagnose``,
``report``, ``batch``) and the Python API. A built-in name wins over a plug-in's; a plug-in that does not load
or is not an :class:`Effect` of that name is left out with a warning that says why.
"""

from __future__ import annotations

from online_id.effects.accelerometer_gravity import AccelerometerGravity
from online_id.effects.accelerometer_lever_arm import AccelerometerLeverArm
from online_id.effects.base import Effect, ExtraState, FitParameter
from online_id.effects.combined_slip import CombinedSlip
from online_id.effects.lateral_velocity_misalignment import LateralVelocityMisalignment
from online_id.effects.load_sensitivity import Downforce, LoadSensitivity
from online_id.effects.load_transfer import LoadTransfer
from online_id.effects.sensor_bias import OFFSET_CHANNELS, SensorBias, sensor_offsets
from online_id.effects.sensor_delay import SensorDelay
from online_id.effects.steering_compliance import SteeringCompliance
from online_id.effects.steering_delay import SteeringDelay
from online_id.effects.tire_saturation import TireSaturation, TireSaturationAxles
from online_id.errors import OnlineIdError

#: The entry-point group of effects other packages provide (see the module docstring).
ENTRY_POINT_GROUP = "online_id.effects"


def _plugins(builtin: dict[str, type[Effect]]) -> dict[str, type[Effect]]:
    """The effects registered under :data:`ENTRY_POINT_GROUP` by installed packages, by name (those that load,
    are :class:`Effect` subclasses of the entry's name and do not take a built-in name; a warning for each other)."""
    import warnings
    from importlib.metadata import entry_points

    found: dict[str, type[Effect]] = {}
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        where = f"effect plug-in {ep.name!r} ({ep.value}"
        if ep.name in builtin or ep.name in found:
            warnings.warn(f"{where}, from {ep.dist.name if ep.dist else 'an unknown package'}): not loaded, the"
                          f" name is taken", stacklevel=2)
            continue
        try:
            cls = ep.load()
        except Exception as exc:  # noqa: BLE001 -- a broken plug-in must not break every command
            warnings.warn(f"{where}): not loaded: {type(exc).__name__}: {exc}", stacklevel=2)
            continue
        if not (isinstance(cls, type) and issubclass(cls, Effect) and cls.name == ep.name):
            warnings.warn(f"{where}): not loaded: not an online_id.effects.Effect subclass named {ep.name!r}",
                          stacklevel=2)
            continue
        found[ep.name] = cls
    return found


class _Registry(dict):
    """The effects by name: the built-in ones, then the plug-ins', which join at the first look (not at import:
    a plug-in's module imports this package, and a command that names no effect pays nothing for the search)."""

    _searched = False

    def _search(self) -> None:
        if not self._searched:
            self._searched = True
            dict.update(self, _plugins(dict(self)))


def _searching(name: str):
    """dict's method ``name``, after the plug-in search."""
    method = getattr(dict, name)

    def look(self, *args):
        self._search()
        return method(self, *args)

    look.__name__ = name
    return look


for _name in ("__getitem__", "__contains__", "__iter__", "__len__", "get", "keys", "values", "items"):
    setattr(_Registry, _name, _searching(_name))


#: Every effect by name: the built-in ones, then those of installed plug-ins (:data:`ENTRY_POINT_GROUP`).
EFFECTS: dict[str, type[Effect]] = _Registry({cls.name: cls for cls in (
    TireSaturation, TireSaturationAxles, LoadTransfer, CombinedSlip, LoadSensitivity, Downforce,
    AccelerometerGravity, AccelerometerLeverArm, LateralVelocityMisalignment, SensorDelay, SteeringDelay, SensorBias,
    SteeringCompliance)})


def __getattr__(name: str):
    if name == "DIAGNOSIS_CANDIDATES":
        # The candidates ``diagnose`` tries by default: every effect but the refinements of another
        # (Effect.refines); a function of the registry, so the plug-ins are among them
        return tuple(n for n, cls in EFFECTS.items() if not cls.refines)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _effect_class(name: str, text: str) -> type[Effect]:
    if name not in EFFECTS:
        raise OnlineIdError(f"--effect {text}: unknown effect {name!r}; choose from {', '.join(EFFECTS)}")
    return EFFECTS[name]


def parse_effect(text: str) -> Effect:
    """An effect from ``NAME=VALUE`` (the syntax of ``online-id simulate --effect``)."""
    name, _, value = text.partition("=")
    return _effect_class(name.strip(), text).parse(value.strip())


def parse_effect_to_estimate(text: str) -> Effect:
    """An effect to estimate from ``NAME[:CHANNEL][:START]`` (``estimate``/``fit --effect``); ``NAME=...``
    as in ``simulate --effect`` is accepted too, the value then being where the estimate starts."""
    sep = "=" if "=" in text else ":"
    name, _, rest = text.partition(sep)
    return _effect_class(name.strip(), text).to_estimate(rest.strip())


__all__ = ["DIAGNOSIS_CANDIDATES", "EFFECTS", "ENTRY_POINT_GROUP", "OFFSET_CHANNELS", "Effect", "ExtraState",
           "FitParameter", "parse_effect", "parse_effect_to_estimate", "sensor_offsets"]
