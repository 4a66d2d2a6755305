"""``sensor_delay``: a time lag on one measured channel.

The logged channel is the true one τ seconds late, y_logged(t) = y(t − τ) (the car at rest before
the run starts). At 4 Hz a 30 ms lag is a 43° phase error: the gap grows with frequency, as Haro
saw. The tool fits τ for each measured channel and keeps the channel that explains most.

Value syntax: ``sensor_delay=CHANNEL:SECONDS``, CHANNEL one of yaw_rate, roll_angle, roll_rate,
lateral_acceleration (for example ``sensor_delay=yaw_rate:0.03``).

Block-mean form: shifting commutes with block averaging, so the block-mean series is shifted by
cubic interpolation.

Filter form (the lagged-output form, :mod:`online_id.filters.lagged`): τ is one extra state. The filter
keeps its model in the steering's time and reads the delayed channel τ̂ later, y_logged(t + τ̂) =
y(t + τ̂ − τ) ≈ y(t) − (τ − τ̂)·ẏ(t): the prediction is the model's own output, and the channel's
sensitivity to τ is −ẏ (ẏ = C·(A x + B δ), the model's exact output rate). Its error against the exact
delay: none at τ̂ = τ but the reading of the logged channel between its samples (cubic Hermite: at 100 Hz
a 4 Hz sine is read to 2.6e-4 of its amplitude, at 1 kHz to 2.5e-7); away from τ̂ = τ the linearisation is
off by (τ − τ̂)²·ÿ/2 (the EKF's ordinary error, gone as τ̂ converges). The price is latency: the filter
holds the samples τ̂ back until the delayed channel has arrived (a live run shows its estimate τ̂ late).
A Padé approximant was the other way: extra dynamic states, an all-pass whose phase error at ωτ = 0.6
(4 Hz, 25 ms) is 1° for the first order, but model states the filters' exact discretisation does not have.
"""

from __future__ import annotations

import numpy as np

from online_id.effects.base import SENSOR_CHANNELS, Effect, ExtraState, FitParameter, parse_channel_value
from online_id.errors import OnlineIdError

#: The filters' prior 1σ of a delay [s]: CAN gateways, filtered gyros and steering servos lag by 0-100 ms.
DELAY_PRIOR_STD = 0.05
#: A delay is fixed by the hardware; a small walk keeps the filter able to follow [s/√s] (0.8 ms over 60 s).
DELAY_RANDOM_WALK = 1e-4


def shift_block_means(series: np.ndarray, time: np.ndarray, delay_s: float) -> np.ndarray:
    """A block-mean series (n,) at block centres ``time`` [s from the run's start] ``delay_s`` late, by cubic
    interpolation, zero before the run (the car at rest)."""
    from scipy.interpolate import CubicSpline  # scipy: not at CLI start-up (the registry is imported there)

    spline = CubicSpline(np.concatenate([[0.0], time]), np.concatenate([[0.0], series]))
    shifted = time - delay_s
    return np.where(shifted > 0, spline(np.clip(shifted, 0, None)), 0.0)


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
        out = outputs.copy()
        col = SENSOR_CHANNELS.index(self.channel)
        out[:, col] = shift_block_means(out[:, col], context.time, self.values["delay_s"])
        return out

    def filter_states(self, known):
        return [ExtraState(group="effects", key=self.label, parameter="delay_s", unit="s", prior_std=DELAY_PRIOR_STD,
                           random_walk=DELAY_RANDOM_WALK, initial=self.values["delay_s"], lags=(self.channel,),
                           bounds=self.fit_bounds("delay_s"))]
