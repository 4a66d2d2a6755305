"""``sensor_bias``: a constant offset on one measured channel or on the steering-wheel angle.

For a measured channel the log reads y + b. For the steering the log reads δH + b while the car
steers by δH: an uncalibrated steering zero makes the car look as if it pulls to one side. Units
are the channel's SI units (rad, rad/s, m/s²).

Value syntax: ``sensor_bias=CHANNEL:VALUE``, CHANNEL one of yaw_rate, roll_angle, roll_rate,
lateral_acceleration, steering_wheel_angle (for example ``sensor_bias=lateral_acceleration:0.3``).
"""

from __future__ import annotations

from online_id.effects.base import SENSOR_CHANNELS, STEERING, Effect, FitParameter, parse_channel_value

_SCALES = {"yaw_rate": 0.01, "roll_angle": 0.002, "roll_rate": 0.01, "lateral_acceleration": 0.1,
           STEERING: 0.02}


class SensorBias(Effect):
    name = "sensor_bias"
    stage = "sensor"
    syntax = "CHANNEL:VALUE (SI units), e.g. lateral_acceleration:0.3 or steering_wheel_angle:0.02"
    summary = "a constant offset on one measured channel or on the steering-wheel angle"

    @classmethod
    def fit_parameters(cls):
        return [FitParameter("bias", "SI", initial=0.0, lower=-10.0, upper=10.0, scale=0.05)]

    @classmethod
    def parse(cls, text):
        channel, b = parse_channel_value(cls.name, text, SENSOR_CHANNELS + (STEERING,))
        return cls(channel=channel, bias=b)

    @classmethod
    def candidates(cls, channels):
        return [cls(channel=c) for c in channels if c in SENSOR_CHANNELS] + [cls(channel=STEERING)]

    def car_steering(self, logged):
        return logged - self.values["bias"] if self.channel == STEERING else logged

    def logged_steering(self, true):
        return true + self.values["bias"] if self.channel == STEERING else true

    def measure(self, outputs, dt):
        if self.channel == STEERING:
            return outputs
        out = outputs.copy()
        out[:, SENSOR_CHANNELS.index(self.channel)] += self.values["bias"]
        return out
