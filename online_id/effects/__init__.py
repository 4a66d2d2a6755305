"""Candidate unmodelled effects: documented extensions of the base model with their own parameters.

Each module holds one effect (see :mod:`online_id.effects.base` for the contract: simulation,
block-mean and filter forms); :data:`EFFECTS` registers them by name for ``simulate --effect``,
``diagnose --effects``, and ``estimate``/``fit --effect``. The package imports no scipy (the CLI
builds its help from the registry at start-up): the model with effects over a whole run lives in
:mod:`online_id.sim.with_effects`.
"""

from __future__ import annotations

from online_id.effects.accelerometer_gravity import AccelerometerGravity
from online_id.effects.base import Effect, ExtraState, FitParameter
from online_id.effects.sensor_bias import OFFSET_CHANNELS, SensorBias, sensor_offsets
from online_id.effects.sensor_delay import SensorDelay
from online_id.effects.steering_compliance import SteeringCompliance
from online_id.effects.steering_delay import SteeringDelay
from online_id.effects.tire_saturation import TireSaturation, TireSaturationAxles
from online_id.errors import OnlineIdError

EFFECTS: dict[str, type[Effect]] = {cls.name: cls for cls in (
    TireSaturation, TireSaturationAxles, AccelerometerGravity, SensorDelay, SteeringDelay, SensorBias,
    SteeringCompliance)}


#: The candidates ``diagnose`` tries by default: every effect but the refinements of another (Effect.refines).
DIAGNOSIS_CANDIDATES: tuple[str, ...] = tuple(n for n, cls in EFFECTS.items() if not cls.refines)


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


__all__ = ["DIAGNOSIS_CANDIDATES", "EFFECTS", "OFFSET_CHANNELS", "Effect", "ExtraState", "FitParameter", "parse_effect",
           "parse_effect_to_estimate", "sensor_offsets"]
