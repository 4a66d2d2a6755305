"""``load_transfer``: the saturating tyres, a μ per axle, on axle loads that braking and traction move.

Braking into a corner loads the front axle and unloads the rear; traction out of it does the opposite. With
the longitudinal acceleration a_x at the centre of gravity (positive forward) and the CG's height hg from the
vehicle file, the axle loads are

    Fz1 = M·(g·l2 − a_x·hg)/L,   Fz2 = M·(g·l1 + a_x·hg)/L   (L = l1 + l2; each at least 5 % of its static load)

(:func:`online_id.vehicle.parameters.axle_loads_at`), and each axle's force follows the tanh law of
``tire_saturation_axles`` on its own load, sample by sample:

    F_i = −μ_i·Fz_i(t) · tanh(D_i·α_i / (μ_i·Fz_i(t)))

The same cornering stiffness at small slip; the peak force moves with the load: under braking the front can
give more, the rear less (a car that turns in and then steps out), under traction the reverse. At a constant
speed it is ``tire_saturation_axles`` exactly: it refines that effect (the diagnosis tries it once a μ per axle
is named, and keeps it when the held-out data say so). The cornering stiffness itself is held at its static
value (no load sensitivity: a stiffness that grows less than linearly with load is not in this law).

The longitudinal acceleration is the run's logged ``longitudinal_acceleration``, or dV/dt from the logged
speed where it is not logged (said where it is used). hg comes from the vehicle file (``[known] hg``).

Value syntax: ``load_transfer=MU_FRONT:MU_REAR`` (for example ``load_transfer=0.9:1.0``). Block-mean form: the
law solved at full rate (the compiled tyre model with the loads of each sample) and averaged. Filter form: the
two μ's as extra states, as ``tire_saturation_axles``, the filters reading each sample's a_x.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from online_id.effects.tire_saturation import TireSaturationAxles
from online_id.errors import OnlineIdError
from online_id.vehicle.parameters import axle_loads_at


class LoadTransfer(TireSaturationAxles):
    """Its fit parameters and value syntax are ``tire_saturation_axles``' (a μ per axle, MU_FRONT:MU_REAR)."""

    name = "load_transfer"
    syntax = ("MU_FRONT:MU_REAR: friction coefficient of each axle, the peak force μ·Fz on axle loads moved by"
              " braking and traction, e.g. 0.9:1.0")
    example = "0.9:1.0"
    summary = ("tyres saturating on axle loads braking and traction move: F_i = −μ_i·Fz_i(a_x)·tanh(D_i·α_i/"
               "(μ_i·Fz_i(a_x))), Fz1,2 = M(g·l2,1 ∓ a_x·hg)/L")
    refines = "tire_saturation_axles"
    note = "needs the run's longitudinal acceleration (logged, or dV/dt from the speed) and the CG height hg"
    moves_loads = True

    def filter_states(self, known):
        return [replace(state, axle_loads=self.axle_loads) for state in super().filter_states(known)]

    def axle_loads(self, known, longitudinal_acceleration=None, speed=None) -> np.ndarray:
        if longitudinal_acceleration is None:
            raise OnlineIdError(f"{self.name}: the axle loads follow the longitudinal acceleration, and this run"
                                " gives none (neither a longitudinal_acceleration column nor a speed to take dV/dt"
                                " from)")
        if not known.hg > 0:
            raise OnlineIdError(f"{self.name}: the vehicle's CG height hg is {known.hg} m; the load transfer needs"
                                " a positive hg ([known] hg in the vehicle file)")
        return axle_loads_at(known, longitudinal_acceleration)
