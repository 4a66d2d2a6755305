"""``tire_saturation``: lateral tyre force saturating with slip.

The base model's tyre force is linear, F_i = −D_i·α_i. Here each axle's force follows

    F_i = −μ·Fz_i · tanh(D_i·α_i / (μ·Fz_i))

with the static axle loads Fz1 = M·g·l2/(l1+l2), Fz2 = M·g·l1/(l1+l2): the same cornering stiffness
at small slip, a peak force μ·Fz_i. μ is friction-like (dimensionless); at 0.4 g a μ of 0.6 takes
about 12 % off the peak force. Haro suspected this for the residuals that grew with amplitude.

Value syntax: ``tire_saturation=MU`` (for example ``tire_saturation=0.6``).

Block-mean form: the force law is solved at full rate and averaged (the base class's identity on
the block means). Filter form: μ is one extra state (both axles; ``tire_saturation:MU`` starts it at
MU), and the filters predict with the saturating law itself (:mod:`online_id.model.tyres`,
:mod:`online_id.filters.tyres`), learning from the whole envelope up to the law's own limit.
"""

from __future__ import annotations

import numpy as np

from online_id.effects.base import Effect, ExtraState, FitParameter, parse_number
from online_id.errors import OnlineIdError
from online_id.model.lateral import PARAMETER_NAMES
from online_id.vehicle.parameters import KnownParameters

G = 9.80665
#: The filters' prior 1σ of μ, and its random walk [1/√s]: dry asphalt from road to race tyres is 0.8-1.8.
MU_PRIOR_STD = 0.5
MU_RANDOM_WALK = 1e-3
_D1, _D2 = PARAMETER_NAMES.index("D1"), PARAMETER_NAMES.index("D2")


def axle_loads(known: KnownParameters) -> np.ndarray:
    """Static vertical loads on the front and rear axle [N]."""
    L = known.l1 + known.l2
    return known.M * G * np.array([known.l2 / L, known.l1 / L])


class TireSaturation(Effect):
    name = "tire_saturation"
    stage = "dynamics"
    syntax = "MU: friction coefficient (peak force = MU·axle load), e.g. 0.6"
    example = "0.6"
    summary = "lateral tyre force saturating with slip: F = −μFz·tanh(Dα/(μFz))"

    @classmethod
    def fit_parameters(cls):
        return [FitParameter("mu", "-", initial=1.5, lower=0.15, upper=20.0, scale=0.5)]

    @classmethod
    def parse(cls, text):
        mu = parse_number(cls.name, text, "MU")
        if mu <= 0:
            raise OnlineIdError(f"--effect {cls.name}: MU must be positive, got {text}")
        return cls(mu=mu)

    def force_law(self, theta, known):
        peak = self.values["mu"] * axle_loads(known)
        stiffness = np.array([theta[_D1], theta[_D2]])

        def law(alpha):
            linear = stiffness * alpha
            return linear - peak * np.tanh(linear / peak)

        return law

    def filter_states(self, known):
        mu = self.values["mu"]
        return [ExtraState(group="effects", key=self.label, parameter="mu", unit="-", prior_std=MU_PRIOR_STD,
                           random_walk=MU_RANDOM_WALK, initial=mu, tyre_axles=(0, 1))]
