"""``steering_delay``: the road wheels follow the logged steering-wheel angle τ late.

A steer-by-wire actuator, a power-steering servo, or a log that holds the steering *command* rather
than the measured angle (autonomous race cars log exactly that): the car steers by

    δ(t) = δH(t − τ) / i_s,      optionally through the actuator's first-order lag T:
    T·δ̇ + δ = δH(t − τ) / i_s.

Every channel then lags the logged steering, where ``sensor_delay`` lags one. At 4 Hz a 60 ms delay is
86° of phase: a base fit hides it in the yaw inertia (Mzz several times too high).

Value syntax: ``steering_delay=SECONDS`` or ``SECONDS:LAG_S`` (for example ``steering_delay=0.06``, or
``steering_delay=0.04:0.02`` for 40 ms and a 20 ms actuator lag). The lag is a property of the simulated
car only: the fits and the filters estimate τ alone. At the frequencies a driver steers a lag T looks like
a delay of about T (the same phase ωT for ωT ≪ 1), but it is also what the front relaxation length does
(b1/V is a first-order lag on the front axle), so τ̂ and b1 share it: on a 40 ms + 20 ms car (30 s chirp
at 500 Hz) ``estimate`` gave τ̂ 54.5 ms and b1 29 % high, Mzz 6.7 %, the others within 3 %.

Block-mean form: the model is linear and time-invariant at a constant speed, so delaying its input
delays every output by the same τ: the block-mean series is shifted by cubic interpolation (as
``sensor_delay`` shifts one channel), and a lag is applied to the block means by the exact first-order
step at the block period. Where the speed changes, this holds to first order in τ·V̇/V.

Filter form: τ is one extra state, a lag of every measured channel and of the speed against the steering
(:attr:`~online_id.effects.base.ExtraState.lags`): the filters keep the model in the steering's time and read
what the car did τ̂ later (:mod:`online_id.filters.lagged`). Exact in the model's time at τ̂ = τ.
"""

from __future__ import annotations

import numpy as np

from online_id.effects.base import SENSOR_CHANNELS, Effect, ExtraState, FitParameter, parse_number
from online_id.effects.sensor_delay import DELAY_PRIOR_STD, DELAY_RANDOM_WALK, shift_block_means
from online_id.errors import OnlineIdError

#: The channels the car's delay reaches: every measured one, and the speed (the filters read them τ later).
LAGGED = SENSOR_CHANNELS + ("speed",)


def first_order_lag(u: np.ndarray, lag_s: float, dt: float) -> np.ndarray:
    """u through T·ẏ + y = u, exact for u held over each period ``dt``, from y(0) = u(0) (at rest)."""
    if lag_s <= 0:
        return u
    a = np.exp(-dt / lag_s)
    y = np.empty_like(u)
    y[0] = u[0]
    for k in range(1, len(u)):
        y[k] = a * y[k - 1] + (1.0 - a) * u[k - 1]
    return y


class SteeringDelay(Effect):
    name = "steering_delay"
    stage = "input"
    syntax = "SECONDS[:LAG_S]: the road wheels follow the logged steering τ late (and through a lag), e.g. 0.06"
    example = "0.06"
    summary = "the road-wheel angle follows the logged steering-wheel angle τ late (actuator, servo, a logged command)"
    short_blocks_only = True

    def __init__(self, channel=None, lag_s: float = 0.0, **values):
        super().__init__(channel, **values)
        self.lag_s = float(lag_s)

    @classmethod
    def fit_parameters(cls):
        return [FitParameter("delay_s", "s", initial=0.005, lower=0.0, upper=0.25, scale=0.01)]

    @classmethod
    def parse(cls, text):
        delay, _, lag = text.partition(":")
        tau = parse_number(cls.name, delay, "SECONDS")
        lag_s = parse_number(cls.name, lag, "LAG_S") if lag else 0.0
        if tau < 0 or lag_s < 0:
            raise OnlineIdError(f"--effect {cls.name}: the delay and the lag must not be negative, got {text}")
        return cls(delay_s=tau, lag_s=lag_s)

    def with_vector(self, vector):
        out = super().with_vector(vector)
        out.lag_s = self.lag_s
        return out

    def to_dict(self):
        d = super().to_dict()
        if self.lag_s:
            d["lag_s"] = self.lag_s
        return d

    def car_steering(self, logged, dt):
        t = np.arange(len(logged)) * dt
        delayed = np.interp(t - self.values["delay_s"], t, logged)  # held at its first value before the run
        return first_order_lag(delayed, self.lag_s, dt)

    def logged_steering(self, true, dt):
        u = np.asarray(true, dtype=float)
        if self.lag_s > 0:  # the lag's exact inverse: u_k = (y_k+1 − a·y_k)/(1 − a)
            a = np.exp(-dt / self.lag_s)
            u = np.concatenate([(u[1:] - a * u[:-1]) / (1.0 - a), u[-1:]])
        t = np.arange(len(u)) * dt
        return np.interp(t + self.values["delay_s"], t, u)  # held at its last value after the run

    def block_means(self, outputs, context):
        out = outputs.copy()
        for col in range(out.shape[1]):
            out[:, col] = shift_block_means(out[:, col], context.time, self.values["delay_s"])
        if self.lag_s > 0:
            out = first_order_lag_blocks(out, self.lag_s, context.block_dt)
        return out

    def filter_states(self, known):
        return [ExtraState(group="effects", key=self.label, parameter="delay_s", unit="s", prior_std=DELAY_PRIOR_STD,
                           random_walk=DELAY_RANDOM_WALK, initial=self.values["delay_s"], lags=LAGGED,
                           bounds=self.fit_bounds("delay_s"))]


def first_order_lag_blocks(blocks: np.ndarray, lag_s: float, block_dt: float) -> np.ndarray:
    """Block means (n, k) through T·ẏ + y = u, by the first-order step at the block period with the input
    linear between block centres (first-order hold): exact for a signal linear over two blocks."""
    a = np.exp(-block_dt / lag_s)
    # y_k+1 = a·y_k + (1 − a)·u_k + (1 − (T/h)·(1 − a))·(u_k+1 − u_k), h the block period
    b1 = 1.0 - lag_s / block_dt * (1.0 - a)
    b0 = (1.0 - a) - b1
    y = np.empty_like(blocks)
    y[0] = blocks[0]
    for k in range(1, len(blocks)):
        y[k] = a * y[k - 1] + b0 * blocks[k - 1] + b1 * blocks[k]
    return y
