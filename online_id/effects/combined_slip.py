"""``combined_slip``: the lateral grip an axle has left while it brakes or drives, on loads braking and traction move.

A tyre's friction is shared between its directions (the friction ellipse, here a circle): an axle carrying a
longitudinal force Fx_i has at most √((μ_i·Fz_i)² − Fx_i²) for cornering. Braking at 1 g with a μ of 1.2 leaves
55 % of the lateral grip; under traction the driven axle alone loses it. The axle loads move with the
longitudinal acceleration as in ``load_transfer`` (Fz1,2 = M·(g·l2,1 ∓ a_x·hg)/L), and the longitudinal force is
the car's, M·a_x, shared between the axles by the brake balance when braking (a_x < 0) and by the drive layout
under traction (the vehicle file's ``[known] brake_front_share`` and ``drive_front_share``: 0.6 and 0, rear-wheel
drive, when it gives none). Each axle's force

    F_i = −P_i · tanh(D_i·α_i / P_i),   P_i = √((μ_i·Fz_i)² − Fx_i²), at least 20 % of μ_i·Fz_i

(:func:`online_id.model.tyres._peaks`): the same cornering stiffness at small slip. It refines ``load_transfer``
(at a constant speed, and without a longitudinal force, it is that law exactly). Left out: the aerodynamic drag,
which decelerates the car without a tyre force (counted here as braking), and a cornering stiffness that falls
with the longitudinal slip (only the peak falls).

Value syntax: ``combined_slip=MU_FRONT:MU_REAR`` (for example ``combined_slip=1.1:1.2``). Block-mean, filter and
fit forms: those of ``load_transfer``, with the longitudinal forces beside the loads.
"""

from __future__ import annotations

import numpy as np

from online_id.effects.load_transfer import LoadTransfer


class CombinedSlip(LoadTransfer):
    name = "combined_slip"
    syntax = ("MU_FRONT:MU_REAR: friction coefficient of each axle, shared between cornering and the braking or"
              " driving force (the friction ellipse) on loads braking and traction move, e.g. 1.1:1.2")
    example = "1.1:1.2"
    summary = ("lateral grip left beside each axle's braking or driving force: peak √((μ_i·Fz_i)² − Fx_i²), Fx from"
               " M·a_x by the brake balance or drive layout, Fz moved by a_x")
    refines = "load_transfer"
    note = ("needs the run's longitudinal acceleration (logged, or dV/dt from the speed), the CG height hg and the"
            " brake balance and drive layout (vehicle file; 0.6 front and rear-wheel drive when not given)")

    def axle_loads(self, known, longitudinal_acceleration=None, speed=None) -> np.ndarray:
        loads = super().axle_loads(known, longitudinal_acceleration)
        ax = np.asarray(longitudinal_acceleration, dtype=float).reshape(-1)
        front = np.where(ax < 0.0, known.brake_front_share, known.drive_front_share)
        force = known.M * ax
        return np.column_stack([loads, front * force, (1.0 - front) * force])
