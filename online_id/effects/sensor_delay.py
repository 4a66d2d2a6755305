"""``sensor_delay``: a time lag on one measured channel.

The logged channel is the true one τ seconds late, y_logged(t) = y(t − τ) (the car at rest before
the run starts). At 4 Hz a 30 ms lag is a 43° phase error: the gap grows with frequency, as Haro
saw. The tool fits τ for each measured channel and keeps the channel that explains most.

Value syntax: ``sensor_delay=CHANNEL:SECONDS``, CHANNEL one of yaw_rate, roll_angle, roll_rate,
lateral_acceleration (for example ``sensor_delay=yaw_rate:0.03``).

Block-mean form: shifting commutes with block averaging, so the block-mean series is shifted, by a
windowed-sinc fractional delay (:func:`shift_block_means`). A cubic spline through the block means did it
until 2026-11-27: exact enough for a 1 kHz log's 10 ms blocks, not for a 100 Hz log's 0.1 s blocks, where a
3 Hz steering is 0.3 cycles a block (the spline's error 5.6 %, the sinc's 6e-6 of the amplitude); the diagnosis
then fitted a 40 ms steering delay as 58 ms and left a gap of 12 noise σ (1.0 after the fix).

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


#: Taps each side of the block-mean shift's fractional-delay filter, and its Kaiser window's β: a sine shifted
#: to 1e-4 of its amplitude up to 0.8 of the blocks' Nyquist frequency (4 Hz in a 100 Hz log's 0.1 s blocks).
SHIFT_TAPS = 16
SHIFT_KAISER_BETA = 8.0


def shift_block_means(series: np.ndarray, time: np.ndarray, delay_s: float) -> np.ndarray:
    """A block-mean series (n,) at evenly spaced block centres ``time`` [s from the run's start] ``delay_s`` late:
    a Kaiser-windowed sinc of :data:`SHIFT_TAPS` taps each side for the fraction of a block, whole blocks by
    indexing; zero before the run (the car at rest). The last blocks, whose taps would reach past the run's end,
    take the cubic spline through the series (as every block did before 2026-11-27): on long blocks the fits shift
    every sample's outputs (:data:`online_id.sim.with_effects.SHIFT_BLOCK_S`), where that is 0.16 s at 100 Hz."""
    x = np.asarray(series, dtype=float)
    n = len(x)
    if n < 2 or delay_s == 0:
        return x.copy() if delay_s == 0 else np.where(np.asarray(time) - delay_s > 0, x, 0.0)
    period = float(np.median(np.diff(time)))
    d = delay_s / period
    whole = int(np.floor(d))
    j = np.arange(-SHIFT_TAPS + 1, SHIFT_TAPS + 1)  # taps on x[k − whole − j]
    h = np.sinc(j - (d - whole)) * np.kaiser(2 * SHIFT_TAPS, SHIFT_KAISER_BETA)
    h /= h.sum()
    front = max(whole + SHIFT_TAPS, 0)
    padded = np.concatenate([np.zeros(front), x])
    body = min(max(n + whole - SHIFT_TAPS + 1, 0), n)  # the blocks whose taps all lie inside the run
    out = np.empty(n)
    out[:body] = np.convolve(padded, h)[np.arange(body) + front - whole + SHIFT_TAPS - 1]
    if body < n:  # the last blocks: the cubic spline through the series, which needs only its past
        from scipy.interpolate import CubicSpline  # scipy: not at CLI start-up (the registry is imported there)

        t = np.asarray(time, dtype=float)
        spline = CubicSpline(np.concatenate([[0.0], t]), np.concatenate([[0.0], x]))
        shifted = t[body:] - delay_s
        out[body:] = np.where(shifted > 0, spline(np.clip(shifted, 0, None)), 0.0)
    return out


class SensorDelay(Effect):
    name = "sensor_delay"
    stage = "sensor"
    syntax = "CHANNEL:SECONDS, e.g. yaw_rate:0.03"
    example = "yaw_rate:0.03"
    summary = "a time lag τ on one measured channel"
    channels = SENSOR_CHANNELS
    short_blocks_only = True

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
