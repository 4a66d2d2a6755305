"""Candidate unmodelled effects: documented extensions of the base model with their own parameters.

Each module holds one effect (see :mod:`online_id.effects.base` for what an effect provides);
:data:`EFFECTS` registers them by name for ``simulate --effect`` and ``diagnose``.
"""

from __future__ import annotations

from online_id.effects.accelerometer_gravity import AccelerometerGravity
from online_id.effects.base import Effect, FitParameter
from online_id.effects.pipeline import predict
from online_id.effects.sensor_bias import SensorBias
from online_id.effects.sensor_delay import SensorDelay
from online_id.effects.steering_compliance import SteeringCompliance
from online_id.effects.tire_saturation import TireSaturation
from online_id.errors import OnlineIdError

EFFECTS: dict[str, type[Effect]] = {cls.name: cls for cls in (
    TireSaturation, AccelerometerGravity, SensorDelay, SensorBias, SteeringCompliance)}


def parse_effect(text: str) -> Effect:
    """An effect from ``NAME=VALUE`` (the syntax of ``online-id simulate --effect``)."""
    name, _, value = text.partition("=")
    name = name.strip()
    if name not in EFFECTS:
        raise OnlineIdError(f"--effect {text}: unknown effect {name!r}; choose from {', '.join(EFFECTS)}")
    return EFFECTS[name].parse(value.strip())


__all__ = ["EFFECTS", "Effect", "FitParameter", "parse_effect", "predict"]
