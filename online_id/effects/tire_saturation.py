"""``tire_saturation`` and ``tire_saturation_axles``: lateral tyre force saturating with slip.

The base model's tyre force is linear, F_i = −D_i·α_i. Here each axle's force follows

    F_i = −μ_i·Fz_i · tanh(D_i·α_i / (μ_i·Fz_i))

with the static axle loads Fz1 = M·g·l2/(l1+l2), Fz2 = M·g·l1/(l1+l2): the same cornering stiffness
at small slip, a peak force μ_i·Fz_i. μ is friction-like (dimensionless); at 0.4 g a μ of 0.6 takes
about 12 % off the peak force. Haro suspected this for the residuals that grew with amplitude.

``tire_saturation`` has one μ for both axles; ``tire_saturation_axles`` one per axle (μ_front, μ_rear).
With one μ and static axle loads both axles reach their peak at the same lateral acceleration: the
model's limit balance is exactly neutral, and driven by a real car's steering at the limit it spins
where the car did not (measured on the race car of realdata/revs_250lm: an open-loop run of the
filters' one-μ estimate spins from 115 s on; with the rear μ 5 % above the front it follows the whole
400 s, yaw-rate error 0.028 rad/s). Per axle, the axle that saturates first is the data's to say
(limit understeer: the front; oversteer: the rear).

Value syntax: ``tire_saturation=MU`` (for example ``tire_saturation=0.6``);
``tire_saturation_axles=MU_FRONT:MU_REAR`` (for example ``tire_saturation_axles=0.9:1.0``).

Block-mean form: the force law is solved at full rate and averaged (the base class's identity on
the block means). Filter form: μ is one extra state (both axles; ``tire_saturation:MU`` starts it at
MU), or two (``tire_saturation_axles:MU_FRONT:MU_REAR``), and the filters predict with the saturating
law itself (:mod:`online_id.model.tyres`, :mod:`online_id.filters.tyre_filters`), learning from the whole
envelope up to the law's own limit.
"""

from __future__ import annotations

import numpy as np

from online_id.effects.base import Effect, ExtraState, FitParameter, parse_number
from online_id.errors import OnlineIdError
from online_id.model.lateral import PARAMETER_NAMES
from online_id.vehicle.parameters import axle_loads

#: The filters' prior 1σ of μ, and its random walk [1/√s]: dry asphalt from road to race tyres is 0.8-1.8, from the
#: fit's start of 1.5 within 2.3σ. Not wider: the UKF spreads its sigma points √n σ from the mean (n = 16 with two μ's),
#: and at 0.5 the lower ones sat at μ ≤ 0 (floored at 0.05: a car on ice, whose prediction dragged the first
#: corrections); at 0.3 they stay above 0.3 from 1.5.
MU_PRIOR_STD = 0.3
MU_RANDOM_WALK = 1e-3
#: Where a fit of μ starts and its bounds (the fit parameters' initial, lower, upper, scale).
MU_FIT = dict(initial=1.5, lower=0.15, upper=20.0, scale=0.5)
_D1, _D2 = PARAMETER_NAMES.index("D1"), PARAMETER_NAMES.index("D2")


class _SaturatingTyres(Effect):
    """The tanh law with a μ per axle from :meth:`tyre_mu`; subclasses say how many μ's there are. Their
    fit parameters are their μ's, in axle order (one for both axles, or front then rear): the polish and the
    filters rely on that order."""

    stage = "dynamics"
    #: which axles each fit parameter's μ acts on, in fit-parameter order
    AXLES: tuple[tuple[int, ...], ...] = ()

    def tyre_mu(self) -> np.ndarray:
        mu = np.empty(2)
        for p, axles in zip(self.fit_parameters(), self.AXLES):
            mu[list(axles)] = self.values[p.name]
        return mu

    def force_law(self, theta, known):
        peak = self.tyre_mu() * axle_loads(known)
        stiffness = np.array([theta[_D1], theta[_D2]])

        def law(alpha):
            linear = stiffness * alpha
            return linear - peak * np.tanh(linear / peak)

        return law

    def filter_states(self, known):
        return [ExtraState(group="effects", key=self.label, parameter=p.name, unit="-", prior_std=MU_PRIOR_STD,
                           random_walk=MU_RANDOM_WALK, initial=self.values[p.name], tyre_axles=axles)
                for p, axles in zip(self.fit_parameters(), self.AXLES)]


def _positive(name: str, text: str, what: str) -> float:
    mu = parse_number(name, text, what)
    if mu <= 0:
        raise OnlineIdError(f"--effect {name}: {what} must be positive, got {text}")
    return mu


class TireSaturation(_SaturatingTyres):
    name = "tire_saturation"
    syntax = "MU: friction coefficient (peak force = MU·axle load), e.g. 0.6"
    example = "0.6"
    summary = "lateral tyre force saturating with slip: F = −μFz·tanh(Dα/(μFz))"
    AXLES = ((0, 1),)

    @classmethod
    def fit_parameters(cls):
        return [FitParameter("mu", "-", **MU_FIT)]

    @classmethod
    def parse(cls, text):
        return cls(mu=_positive(cls.name, text, "MU"))


class TireSaturationAxles(_SaturatingTyres):
    name = "tire_saturation_axles"
    syntax = "MU_FRONT:MU_REAR: friction coefficient of each axle (peak force = MU·axle load), e.g. 0.9:1.0"
    example = "0.9:1.0"
    summary = "tyre force saturating with slip, a μ per axle: F_i = −μ_i·Fz_i·tanh(D_i·α_i/(μ_i·Fz_i))"
    refines = "tire_saturation"
    AXLES = ((0,), (1,))

    @classmethod
    def fit_parameters(cls):
        return [FitParameter("mu_front", "-", **MU_FIT), FitParameter("mu_rear", "-", **MU_FIT)]

    @classmethod
    def parse(cls, text):
        front, sep, rear = text.partition(":")
        if not sep:
            raise OnlineIdError(f"--effect {cls.name}={text}: expected MU_FRONT:MU_REAR, e.g. {cls.example}")
        return cls(mu_front=_positive(cls.name, front, "MU_FRONT"), mu_rear=_positive(cls.name, rear, "MU_REAR"))
