"""``steering_compliance``: the road-wheel angle gives way to the front lateral force.

The road-wheel angle is δ = δH/i_s − c·F_y1 with F_y1 = −D1·α1 the front axle force: compliance c
[rad/N] (given in deg/kN, the unit of steering-system data sheets).

**In this model the effect is an exact re-parametrisation, not a new behaviour.** Substituting δ
into the front relaxation (eq 4) gives b1·α̇1 = … − V·(1 + c·D1)·α1 − V·δH/i_s; with
α̃1 = (1 + c·D1)·α1 the equations are the base model's with

    D1' = D1 / (1 + c·D1),   b1' = b1 / (1 + c·D1),

at every speed. No run can tell compliance from a softer front tyre with a shorter relaxation
length: a fit of the base model absorbs it completely (its D1 and b1 come out low), so the
diagnosis can never show a held-out gain for it. It can be told apart only against a trusted D1
(tyre test-rig data), which this tool reports as a note. It is simulated exactly through that
identity (see the test that checks it against the equations written out). For the same reason it
has no filter form: an extra state for c would be unobservable beside D1 and b1.

Value syntax: ``steering_compliance=DEG_PER_KN`` (for example ``steering_compliance=0.15``).
"""

from __future__ import annotations

import numpy as np

from online_id.effects.base import Effect, FitParameter, parse_number
from online_id.errors import OnlineIdError
from online_id.model.lateral import PARAMETER_NAMES

_D1, _B1 = PARAMETER_NAMES.index("D1"), PARAMETER_NAMES.index("b1")
RAD_PER_N_PER_DEG_PER_KN = np.pi / 180 / 1000


class SteeringCompliance(Effect):
    name = "steering_compliance"
    stage = "dynamics"
    syntax = "DEG_PER_KN: road-wheel angle lost per kN of front lateral force, e.g. 0.15"
    example = "0.15"
    summary = "road-wheel angle reduced in proportion to the front lateral force (≡ lower D1 and b1)"
    note = ("exactly equivalent to the base model with a lower D1 and b1: no run can show it;"
            " compare the fitted D1 with tyre data instead")

    @classmethod
    def fit_parameters(cls):
        return [FitParameter("compliance_deg_per_kn", "deg/kN", initial=0.05, lower=0.0, upper=5.0, scale=0.1)]

    @classmethod
    def parse(cls, text):
        c = parse_number(cls.name, text, "DEG_PER_KN")
        if c < 0:
            raise OnlineIdError(f"--effect {cls.name}: compliance must not be negative, got {text}")
        return cls(compliance_deg_per_kn=c)

    def transform_theta(self, theta, known):
        c = self.values["compliance_deg_per_kn"] * RAD_PER_N_PER_DEG_PER_KN
        out = np.array(theta, dtype=float, copy=True)
        factor = 1.0 + c * out[_D1]
        out[_D1] /= factor
        out[_B1] /= factor
        return out

    def filter_states(self, known):
        raise OnlineIdError(f"{self.label}: no filter form: {self.note}")
