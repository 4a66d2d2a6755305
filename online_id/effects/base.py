"""What an unmodelled effect is: a documented extension of the base model with its own parameters.

An effect acts at one stage of the path from the driver's hands to the logged channels:

- ``input``: between the logged steering-wheel angle and the angle the car really sees
  (:meth:`Effect.car_steering`, and its inverse :meth:`Effect.logged_steering` for simulation);
- ``dynamics``: inside the model, either as an exact re-parametrisation
  (:meth:`Effect.transform_theta`) or as an extra force law of the slip angles
  (:meth:`Effect.force_law`, see :mod:`online_id.sim.forces`);
- ``sensor``: between the true outputs and the logged channels (:meth:`Effect.measure`).

A new effect is a module in this folder with one :class:`Effect` subclass, registered in
``online_id/effects/__init__.py``. It needs a ``name``, its ``syntax`` for ``simulate --effect``,
its fit parameters (:meth:`Effect.fit_parameters`) and the hooks of its stage.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from online_id.errors import OnlineIdError
from online_id.model.lateral import OUTPUT_NAMES
from online_id.vehicle.parameters import KnownParameters

#: Channels a sensor effect can sit on (the model outputs, in order).
SENSOR_CHANNELS: tuple[str, ...] = OUTPUT_NAMES
STEERING = "steering_wheel_angle"


@dataclass(frozen=True)
class FitParameter:
    """One extra parameter: name, unit, start of the fit, bounds and typical size (for scaling)."""

    name: str
    unit: str
    initial: float
    lower: float
    upper: float
    scale: float


class Effect:
    """Base class. An instance holds the effect's parameter values (and channel, where it has one)."""

    name: ClassVar[str]
    stage: ClassVar[str]  # "input", "dynamics" or "sensor"
    syntax: ClassVar[str]  # the value syntax of ``simulate --effect NAME=VALUE``
    summary: ClassVar[str]

    def __init__(self, channel: str | None = None, **values: float):
        self.channel = channel
        names = [p.name for p in self.fit_parameters()]
        unknown = set(values) - set(names)
        if unknown:
            raise ValueError(f"{self.name}: unknown parameter(s) {', '.join(sorted(unknown))}")
        self.values = {p.name: float(values.get(p.name, p.initial)) for p in self.fit_parameters()}

    # --- description -------------------------------------------------------------------------
    @classmethod
    def fit_parameters(cls) -> list[FitParameter]:
        raise NotImplementedError

    @classmethod
    def parse(cls, text: str) -> Effect:
        """The effect from the value part of ``NAME=VALUE`` (see :attr:`syntax`)."""
        raise NotImplementedError

    @classmethod
    def candidates(cls, channels: tuple[str, ...]) -> list[Effect]:
        """Starting instances for a fit on a run with the given measured channels."""
        return [cls()]

    @property
    def label(self) -> str:
        return f"{self.name}({self.channel})" if self.channel else self.name

    def with_vector(self, vector) -> Effect:
        """A copy with the fit parameters set from ``vector`` (in :meth:`fit_parameters` order)."""
        values = dict(zip([p.name for p in self.fit_parameters()], np.asarray(vector, dtype=float)))
        return type(self)(channel=self.channel, **values)

    def vector(self) -> np.ndarray:
        return np.array([self.values[p.name] for p in self.fit_parameters()])

    def to_dict(self) -> dict:
        d = {"name": self.name, **self.values}
        if self.channel:
            d["channel"] = self.channel
        return d

    # --- hooks (identity by default) ---------------------------------------------------------
    def car_steering(self, logged: np.ndarray) -> np.ndarray:
        """Steering-wheel angle the car sees, from the logged one [rad]."""
        return logged

    def logged_steering(self, true: np.ndarray) -> np.ndarray:
        """Inverse of :meth:`car_steering` (used by the simulator)."""
        return true

    def transform_theta(self, theta: np.ndarray, known: KnownParameters) -> np.ndarray:
        """Base-model parameters that reproduce the effect exactly, where it is a re-parametrisation."""
        return theta

    def force_law(self, theta: np.ndarray, known: KnownParameters):
        """A correction to the linear tyre forces (see :mod:`online_id.sim.forces`), or None."""
        return None

    def measure(self, outputs: np.ndarray, dt: float) -> np.ndarray:
        """Logged outputs (N, 4) from the true ones."""
        return outputs


def parse_number(effect: str, text: str, what: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise OnlineIdError(f"--effect {effect}: {what} must be a number, got {text!r}") from None
    if not np.isfinite(value):
        raise OnlineIdError(f"--effect {effect}: {what} must be finite, got {text!r}")
    return value


def parse_channel_value(effect: str, text: str, allowed: tuple[str, ...]) -> tuple[str, float]:
    channel, sep, value = text.partition(":")
    if not sep:
        raise OnlineIdError(f"--effect {effect}={text}: expected CHANNEL:VALUE with CHANNEL one of"
                            f" {', '.join(allowed)}")
    if channel not in allowed:
        raise OnlineIdError(f"--effect {effect}: unknown channel {channel!r}; choose from {', '.join(allowed)}")
    return channel, parse_number(effect, value, "the value")
