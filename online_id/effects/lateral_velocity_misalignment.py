"""``lateral_velocity_misalignment``: the lateral-velocity sensor is turned in yaw against the car.

An INS or an optical sideslip sensor (a Correvit) measures the velocity along its own axes. Mounted with its x axis
ε to the left of the car's (ISO 8855: yaw positive to the left), it reads

    v_y,logged = v_y·cos ε − V·sin ε

an offset of −ε·V: growing with the speed, not a constant in m/s (the reason ``sensor_bias`` leaves this channel
out). 0.1° at 40 m/s is 0.07 m/s, several times an INS's noise; a sideslip estimator reading that channel is then
wrong by ε at every speed. In the filters' units (the lateral velocity per unit speed, the sideslip angle β =
v_y/V) it is a constant: β_logged = β·cos ε − sin ε ≈ β − ε, exact to ε²/2 (1.5e-6 at 0.1°).

Value syntax: ``lateral_velocity_misalignment=RAD`` (for example ``lateral_velocity_misalignment=0.003``).

Simulation and block-mean forms: the formula above with each sample's speed (a block's mean of V·sin ε is sin ε
times its mean speed: exact). Filter form: ε is one extra state, the sideslip channel's offset −ε.
"""

from __future__ import annotations

import numpy as np

from online_id.effects.base import Effect, ExtraState, FitParameter, parse_number
from online_id.errors import OnlineIdError
from online_id.model.lateral import OUTPUT_NAMES

_VY = OUTPUT_NAMES.index("lateral_velocity")
#: The largest |ε| a fit may take [rad] (6°: a sensor bolted on that crooked would be seen by eye).
MAX_MISALIGNMENT_RAD = 0.1
#: 1σ of ε before any data [rad]: a sensor mounted by eye, about 1°.
MISALIGNMENT_PRIOR_STD = np.deg2rad(1.0)
#: A mounting does not drift; a small walk keeps the filter able to follow [rad/√s].
MISALIGNMENT_RANDOM_WALK = 1e-6


class LateralVelocityMisalignment(Effect):
    name = "lateral_velocity_misalignment"
    stage = "sensor"
    syntax = "RAD: the lateral-velocity sensor's yaw misalignment ε (its x axis ε to the left of the car's), e.g. 0.003"
    example = "0.003"
    summary = ("the lateral-velocity sensor turned ε in yaw: v_y,logged = v_y·cos ε − V·sin ε (an offset growing with"
               " speed)")
    acts_on = "lateral_velocity"
    reads_speed = True

    @classmethod
    def fit_parameters(cls):
        return [FitParameter("yaw_rad", "rad", initial=0.0, lower=-MAX_MISALIGNMENT_RAD, upper=MAX_MISALIGNMENT_RAD,
                             scale=0.005)]

    @classmethod
    def parse(cls, text):
        eps = parse_number(cls.name, text, "RAD")
        if abs(eps) > MAX_MISALIGNMENT_RAD:
            raise OnlineIdError(f"--effect {cls.name}: a misalignment of {eps:g} rad is beyond"
                                f" ±{MAX_MISALIGNMENT_RAD:g} rad (a value in degrees?)")
        return cls(yaw_rad=eps)

    def measure(self, outputs, dt):
        raise OnlineIdError(f"{self.label}: the misaligned sensor's reading depends on the speed (measure_at)")

    def measure_at(self, outputs, dt, speed):
        eps = self.values["yaw_rad"]
        out = outputs.copy()
        out[:, _VY] = outputs[:, _VY] * np.cos(eps) - np.broadcast_to(speed, len(outputs)) * np.sin(eps)
        return out

    def block_means(self, outputs, context):
        if context.speed is None:
            raise OnlineIdError(f"{self.label}: the block means need the blocks' speeds")
        return self.measure_at(outputs, context.block_dt, context.speed)

    def filter_states(self, known):
        output = np.zeros(len(OUTPUT_NAMES))
        output[_VY] = -1.0  # (the filters' lateral velocity is per unit speed: β − ε)
        return [ExtraState(group="effects", key=self.label, parameter="yaw_rad", unit="rad",
                           prior_std=float(MISALIGNMENT_PRIOR_STD), random_walk=MISALIGNMENT_RANDOM_WALK,
                           initial=self.values["yaw_rad"], output=tuple(output),
                           bounds=self.fit_bounds("yaw_rad"))]
