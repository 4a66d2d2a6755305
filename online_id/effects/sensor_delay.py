"""``sensor_delay``: a time lag on one measured channel.

The logged channel is the true one τ seconds late, y_logged(t) = y(t − τ) (the car at rest before
the run starts). At 4 Hz a 30 ms lag is a 43° phase error: the gap grows with frequency, as Haro
saw. The tool fits τ for each measured channel and keeps the channel that explains most.

Value syntax: ``sensor_delay=CHANNEL:SECONDS``, CHANNEL one of yaw_rate, roll_angle, roll_rate,
lateral_acceleration (for example ``sensor_delay=yaw_rate:0.03``).
"""

from __future__ import annotations

import numpy as np

from online_id.effects.base import SENSOR_CHANNELS, Effect, FitParameter, parse_channel_value
from online_id.errors import OnlineIdError


class SensorDelay(Effect):
    name = "sensor_delay"
    stage = "sensor"
    syntax = "CHANNEL:SECONDS, e.g. yaw_rate:0.03"
    summary = "a time lag τ on one measured channel"

    @classmethod
    def fit_parameters(cls):
        return [FitParameter("delay_s", "s", initial=0.005, lower=0.0, upper=0.25, scale=0.01)]

    @classmethod
    def parse(cls, text):
        channel, tau = parse_channel_value(cls.name, text, SENSOR_CHANNELS)
        if tau < 0:
            raise OnlineIdError(f"--effect {cls.name}: the delay must not be negative, got {tau}")
        return cls(channel=channel, delay_s=tau)

    @classmethod
    def candidates(cls, channels):
        return [cls(channel=c) for c in channels if c in SENSOR_CHANNELS]

    def measure(self, outputs, dt):
        out = outputs.copy()
        col = SENSOR_CHANNELS.index(self.channel)
        t = np.arange(len(outputs)) * dt
        out[:, col] = np.interp(t - self.values["delay_s"], t, outputs[:, col], left=0.0)
        return out
