"""``accelerometer_lever_arm``: the lateral accelerometer sits ahead of (or behind) the centre of gravity.

A rigid body turning at yaw rate r: a point x_a metres ahead of the CG (along the car's x axis, ISO 8855)
accelerates sideways by ṙ·x_a more than the CG (and by −r²·x_a along x, which the lateral channel does not
see). An IMU bolted under the dashboard, a logger in the boot or a phone on the windscreen logs

    a_y,logged = a_y + x_a·ṙ

The base model compares the channel with the CG's a_y: the term grows with the yaw acceleration, so it shows
at turn-in and in a fast slalom (at 3 Hz and 20 °/s of yaw rate, ṙ is 6.6 rad/s²: 0.66 m/s² at 10 cm ... 6.6 at
1 m), and looks to a fit like a stiffer or softer front axle. The effect's parameter is x_a [m], positive
ahead of the CG. A log whose a_y was moved to the CG by the logger (the race car's ``ayCG``) has x_a = 0.

Value syntax: ``accelerometer_lever_arm=METRES`` (for example ``accelerometer_lever_arm=1.2``).

Simulation form: ṙ of the simulated yaw rate by sixth-order finite differences (:func:`rate_of`: at a logger's
100 Hz a 4 Hz yaw rate's derivative to 5e-5 of its size, at 1 kHz to 1e-10). Block-mean form: the derivative
commutes with the block average, so the mean of ṙ over a block is the derivative of the block-mean series,
the same differences over the block centres (short blocks); on blocks longer than the fits' shift limit, on
every sample's outputs, then averaged (as a delay: :data:`online_id.sim.with_effects.SHIFT_BLOCK_S`).

No filter form yet: the online filters' outputs are C·x (+ D·δ) with C fixed between linearisation points, and
ṙ's row of the model, C_r·A(θ), moves with the parameters being estimated; an x_a the diagnosis finds is
reported, not carried online (``carry.not_online``). Measure the sensor's position instead where the car is
at hand.
"""

from __future__ import annotations

import numpy as np

from online_id.effects.base import Effect, FitParameter, parse_number
from online_id.errors import OnlineIdError
from online_id.model.lateral import OUTPUT_NAMES

_R, _AY = OUTPUT_NAMES.index("yaw_rate"), OUTPUT_NAMES.index("lateral_acceleration")
#: The largest |x_a| a fit may take [m]: a sensor anywhere in a car's length.
MAX_LEVER_ARM_M = 3.0


#: Sixth-order finite-difference weights for the first derivative (×1/60h) on seven points: the central stencil
#: and the three one-sided ones for the first samples (the last samples' are these reversed, with the sign flipped).
_CENTRAL = np.array([-1.0, 9.0, -45.0, 0.0, 45.0, -9.0, 1.0]) / 60.0
_EDGE = np.array([[-147.0, 360.0, -450.0, 400.0, -225.0, 72.0, -10.0],
                  [-10.0, -77.0, 150.0, -100.0, 50.0, -15.0, 2.0],
                  [2.0, -24.0, -35.0, 80.0, -30.0, 8.0, -1.0]]) / 60.0


def rate_of(series: np.ndarray, spacing: float) -> np.ndarray:
    """The time derivative of an evenly sampled ``series`` (n,) [unit/s], sixth order throughout: the central
    seven-point stencil inside, the one-sided ones on the three first and last samples. A sine of ω·h = 0.25
    (4 Hz at 100 Hz) to 2e-6 of its derivative inside, 5e-5 at the ends. Fewer than seven samples: numpy's
    second-order ``gradient`` (fewer than two: zeros)."""
    y = np.asarray(series, dtype=float)
    n = len(y)
    if n < 2:
        return np.zeros(n)
    if n < 7:
        return np.gradient(y, spacing, edge_order=2 if n > 2 else 1)
    out = np.empty(n)
    out[3:-3] = sum(w * y[i:n - 6 + i] for i, w in enumerate(_CENTRAL) if w)
    out[:3] = _EDGE @ y[:7]
    out[-3:] = -(_EDGE @ y[:-8:-1])[::-1]
    return out / spacing


class AccelerometerLeverArm(Effect):
    name = "accelerometer_lever_arm"
    stage = "sensor"
    syntax = "METRES: the accelerometer's position ahead of the centre of gravity (negative behind), e.g. 1.2"
    example = "1.2"
    summary = "the lateral accelerometer sits x_a ahead of the CG: a_y,logged = a_y + x_a·ṙ"
    note = "no filter form yet: reported with its x_a, not carried online; measure the sensor's position"
    acts_on = "lateral_acceleration"
    short_blocks_only = True  # (a derivative: on long blocks, on every sample's outputs, then averaged)

    @classmethod
    def fit_parameters(cls):
        return [FitParameter("x_m", "m", initial=0.0, lower=-MAX_LEVER_ARM_M, upper=MAX_LEVER_ARM_M, scale=0.3)]

    @classmethod
    def parse(cls, text):
        x = parse_number(cls.name, text, "METRES")
        if abs(x) > MAX_LEVER_ARM_M:
            raise OnlineIdError(f"--effect {cls.name}: a lever arm of {x:g} m is beyond any car's length (at most"
                                f" ±{MAX_LEVER_ARM_M:g} m)")
        return cls(x_m=x)

    def measure(self, outputs, dt):
        out = outputs.copy()
        out[:, _AY] += self.values["x_m"] * rate_of(outputs[:, _R], dt)
        return out

    def block_means(self, outputs, context):
        # d/dt commutes with the block average: the block means' own derivative over the block centres
        return self.measure(outputs, context.block_dt)

    def car_lateral_acceleration(self, logged, yaw_rate, dt):
        return logged - self.values["x_m"] * rate_of(yaw_rate, dt)

    def filter_states(self, known):
        raise OnlineIdError(f"{self.label}: no filter form yet (ṙ's row of the model moves with the estimated"
                            " parameters); the diagnosis reports x_a and the batch fit carries it: online-id fit LOG"
                            f" --effect {self.name}:{self.values['x_m']:.6g}")
