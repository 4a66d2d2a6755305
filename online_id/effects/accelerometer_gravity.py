"""``accelerometer_gravity``: the lateral accelerometer rides on the rolling body.

Fixed to the sprung mass, its axis tilts with the roll angle φ and it senses the specific force
along that axis: a_y·cos φ + g·sin φ (ISO 8855: positive roll tilts the +y axis upwards). The base
model compares the measured channel with a_y alone. The effect's parameter k scales the gravity
term (1 for a sensor on the body, 0 for one on a roll-free platform):

    a_y,measured = a_y·cos φ + k·g·sin φ

Value syntax: ``accelerometer_gravity=K`` (``accelerometer_gravity=1`` for the full effect).

Filter form: k is an extra state entering a_y as k·g·φ (first order in φ: at 2° of roll,
cos φ and sin φ/φ differ from 1 by 6e-4 and 2e-4).
"""

from __future__ import annotations

import numpy as np

from online_id.effects.base import Effect, ExtraState, FitParameter, parse_number
from online_id.model.lateral import N_STATES, OUTPUT_NAMES, PHI
from online_id.units import G

_PHI, _AY = OUTPUT_NAMES.index("roll_angle"), OUTPUT_NAMES.index("lateral_acceleration")
#: 1σ of k before any data: between no effect (0) and the full effect (1) or beyond (-).
K_PRIOR_STD = 1.0
#: k is a property of the installation and does not drift; a small walk keeps the filter able to follow.
K_RANDOM_WALK = 1e-4


class AccelerometerGravity(Effect):
    name = "accelerometer_gravity"
    stage = "sensor"
    syntax = "K: share of g·sin(roll) the accelerometer senses, 1 on the body, e.g. 1"
    example = "1"
    summary = "the lateral accelerometer also senses g·sin φ"

    @classmethod
    def fit_parameters(cls):
        return [FitParameter("k", "-", initial=0.0, lower=-3.0, upper=3.0, scale=0.5)]

    @classmethod
    def parse(cls, text):
        return cls(k=parse_number(cls.name, text or "1", "K"))

    def measure(self, outputs, dt):
        out = outputs.copy()
        phi = outputs[:, _PHI]
        out[:, _AY] = outputs[:, _AY] * np.cos(phi) + self.values["k"] * G * np.sin(phi)
        return out

    def block_means(self, outputs, context):
        # cos φ and sin φ of a block mean: exact to O(φ²) of the variation within the block
        return self.measure(outputs, context.block_dt)

    def filter_states(self, known):
        coupling = np.zeros((len(OUTPUT_NAMES), N_STATES))
        coupling[_AY, PHI] = G  # a_y += k·g·φ
        return [ExtraState(group="effects", key=self.label, parameter="k", unit="-", prior_std=K_PRIOR_STD,
                           random_walk=K_RANDOM_WALK, initial=self.values["k"],
                           output_state=tuple(map(tuple, coupling)))]
