"""``sensor_bias``: a constant offset on one measured channel or on the steering-wheel angle.

For a measured channel the log reads y + b. For the steering the log reads δH + b while the car
steers by δH: an uncalibrated steering zero makes the car look as if it pulls to one side. Units
are the channel's SI units (rad, rad/s, m/s²).

Value syntax: ``sensor_bias=CHANNEL:VALUE``, CHANNEL one of yaw_rate, roll_angle, roll_rate,
lateral_acceleration, steering_wheel_angle (for example ``sensor_bias=lateral_acceleration:0.3``).

Filter form: the offset is an extra state (as deployed estimators learn a gyro bias, or openpilot's
``paramsd`` the steering-angle offset): identity sensitivity on its output channel, and on the
steering it enters like the input, δ = (δH − b)/i_s.
"""

from __future__ import annotations

import numpy as np

from online_id.effects.base import (
    SENSOR_CHANNELS,
    STEERING,
    BlockContext,
    Effect,
    ExtraState,
    FitParameter,
    parse_channel_value,
)
from online_id.units import CHANNEL_UNITS

_SCALES = {"yaw_rate": 0.01, "roll_angle": 0.002, "roll_rate": 0.01, "lateral_acceleration": 0.1,
           STEERING: 0.02}

#: 1σ of an offset before any data, per channel [SI], from sensor specifications:
#: - yaw_rate, roll_rate: the zero-rate offset of automotive MEMS gyros (ESC yaw-rate sensors) is
#:   specified within about ±1-3 °/s over temperature and life: 2 °/s.
#: - lateral_acceleration: a sensor offset of a few 0.01 g plus mounting tilt and road cross-slope
#:   (a 3 % slope alone reads 0.3 m/s²): 0.5 m/s².
#: - roll_angle: levelling of the roll reference (IMU mounting, a loaded car): 1°.
#: - steering_wheel_angle: the sensor zero after alignment or service; openpilot's paramsd accepts
#:   steering-angle offsets of several degrees: 5° at the steering wheel.
OFFSET_PRIOR_STD = {"yaw_rate": np.deg2rad(2.0), "roll_rate": np.deg2rad(2.0), "lateral_acceleration": 0.5,
                    "roll_angle": np.deg2rad(1.0), STEERING: np.deg2rad(5.0)}
#: Random-walk growth of an offset per √s [SI/√s]: slow drift with temperature, small against the
#: prior so that a minute of data pins the offset (over 60 s the yaw-rate offset may wander
#: 0.06 °/s, the lateral acceleration's 0.008 m/s²).
OFFSET_RANDOM_WALK = {"yaw_rate": 1e-4, "roll_rate": 1e-4, "lateral_acceleration": 1e-3,
                      "roll_angle": 1e-5, STEERING: 1e-4}
#: The measured channels an offset may sit on: not the lateral velocity, whose usual error (a sensor misaligned
#: in yaw by ε reads ε·V) is no constant in m/s, and which the filters work per unit speed (issue 38): that error is
#: ``lateral_velocity_misalignment``.
BIASED_CHANNELS: tuple[str, ...] = tuple(c for c in SENSOR_CHANNELS if c in OFFSET_PRIOR_STD)


class SensorBias(Effect):
    name = "sensor_bias"
    stage = "sensor"
    syntax = "CHANNEL:VALUE (SI units), e.g. lateral_acceleration:0.3 or steering_wheel_angle:0.02"
    example = "lateral_acceleration:0.3"
    summary = "a constant offset on one measured channel or on the steering-wheel angle"
    channels = BIASED_CHANNELS + (STEERING,)

    def __init__(self, channel=None, **values):
        super().__init__(channel, **values)
        if self.channel == STEERING:
            self.stage = "input"  # the steering offset acts before the car

    @classmethod
    def fit_parameters(cls):
        return [FitParameter("bias", "SI", initial=0.0, lower=-10.0, upper=10.0, scale=0.05)]

    @classmethod
    def parse(cls, text):
        channel, b = parse_channel_value(cls.name, text, cls.channels)
        return cls(channel=channel, bias=b)

    @classmethod
    def candidates(cls, channels):
        return [cls(channel=c) for c in channels if c in BIASED_CHANNELS] + [cls(channel=STEERING)]

    def car_steering(self, logged, dt):
        return logged - self.values["bias"] if self.channel == STEERING else logged

    def logged_steering(self, true, dt):
        return true + self.values["bias"] if self.channel == STEERING else true

    def measure(self, outputs, dt):
        if self.channel == STEERING:
            return outputs
        out = outputs.copy()
        out[:, SENSOR_CHANNELS.index(self.channel)] += self.values["bias"]
        return out

    def block_means(self, outputs, context: BlockContext):
        if self.channel == STEERING:  # the model is linear: superpose the response to a constant steering
            return outputs - self.values["bias"] * context.unit_steering_response()
        return self.measure(outputs, context.block_dt)

    def car_lateral_acceleration(self, logged, yaw_rate, dt):
        return logged - self.values["bias"] if self.channel == "lateral_acceleration" else logged

    def filter_states(self, known):
        output = np.zeros(len(SENSOR_CHANNELS))
        steering = 0.0
        if self.channel == STEERING:
            steering = -1.0 / known.steering_ratio  # δ = (δH − b)/i_s
        else:
            output[SENSOR_CHANNELS.index(self.channel)] = 1.0
        return [ExtraState(group="offsets", key=self.channel, parameter="bias", unit=CHANNEL_UNITS[self.channel],
                           prior_std=float(OFFSET_PRIOR_STD[self.channel]),
                           random_walk=OFFSET_RANDOM_WALK[self.channel], initial=self.values["bias"],
                           output=tuple(output), steering=steering)]


#: The offsets ``estimate --offsets`` learns: the gyro's and the accelerometer's zero, and the
#: steering-angle zero (the ones deployed estimators track; roll sensors are levelled at install).
OFFSET_CHANNELS: tuple[str, ...] = ("yaw_rate", "lateral_acceleration", STEERING)


def sensor_offsets(channels=OFFSET_CHANNELS) -> list[SensorBias]:
    """Offsets to estimate, one :class:`SensorBias` per channel, starting at zero."""
    return [SensorBias(channel=c) for c in channels]
