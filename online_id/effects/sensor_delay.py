"""``sensor_delay``: a time lag on one measured channel.

The logged channel is the true one τ seconds late, y_logged(t) = y(t − τ) (the car at rest before
the run starts). At 4 Hz a 30 ms lag is a 43° phase error: the gap grows with frequency, as Haro
saw. The tool fits τ for each measured channel and keeps the channel that explains most.

Value syntax: ``sensor_delay=CHANNEL:SECONDS``, CHANNEL one of yaw_rate, roll_angle, roll_rate,
lateral_acceleration (for example ``sensor_delay=yaw_rate:0.03``).

Block-mean form: shifting commutes with block averaging, so the block-mean series is shifted by
cubic interpolation. No filter form: a delay needs the state's history over τ, not a finite
extra state with a linear sensitivity.
"""

from __future__ import annotations

import numpy as np

from online_id.effects.base import SENSOR_CHANNELS, Effect, FitParameter, parse_channel_value
from online_id.errors import OnlineIdError


class SensorDelay(Effect):
    name = "sensor_delay"
    stage = "sensor"
    syntax = "CHANNEL:SECONDS, e.g. yaw_rate:0.03"
    example = "yaw_rate:0.03"
    summary = "a time lag τ on one measured channel"
    channels = SENSOR_CHANNELS

    @classmethod
    def fit_parameters(cls):
        return [FitParameter("delay_s", "s", initial=0.005, lower=0.0, upper=0.25, scale=0.01)]

    @classmethod
    def parse(cls, text):
        channel, tau = parse_channel_value(cls.name, text, cls.channels)
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

    def block_means(self, outputs, context):
        from scipy.interpolate import CubicSpline  # scipy: not at CLI start-up (the registry is imported there)

        out = outputs.copy()
        col = SENSOR_CHANNELS.index(self.channel)
        t = context.time
        spline = CubicSpline(np.concatenate([[0.0], t]), np.concatenate([[0.0], out[:, col]]))
        shifted = t - self.values["delay_s"]
        out[:, col] = np.where(shifted > 0, spline(np.clip(shifted, 0, None)), 0.0)
        return out

    def filter_states(self, known):
        raise OnlineIdError(f"{self.label}: a delay has no filter form (the filter would need the state's"
                            " history over the delay, not one extra state); fit it with 'online-id diagnose'"
                            " or shift the channel before estimating")
