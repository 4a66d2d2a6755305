"""``load_sensitivity``: each axle's whole force curve following its load, less than linearly, and shrinking with
its braking or driving force.

A tyre's cornering stiffness grows with its vertical load, but less than in proportion (a heavier tyre deflects
more and gives less force per newton of load: its load sensitivity); its peak force does the same. And the force a
tyre carries in the longitudinal direction takes from the lateral one over the whole curve, not only at its peak.
``load_transfer`` and ``combined_slip`` keep the cornering stiffness at its static value and move the peak alone;
on the race car of realdata/revs_250lm the data say otherwise: at a given slip angle the rear axle's lateral force
(from a_y, ṙ and the INS's v_y) is 12-22 % lower under braking and under hard traction than coasting, already at
slip angles far below the peak (docs/measured.md).

Each axle's force is its static curve scaled:

    F_i = −k_i·s_i · μ_i·Fz_i⁰ · tanh(D_i·α_i / (μ_i·Fz_i⁰)),   k_i = (Fz_i/Fz_i⁰)^p,
    s_i = √(1 − (Fx_i / (k_i·μ_i·Fz_i⁰))²) (at least 20 %)

with Fz_i the axle loads braking and traction move (``load_transfer``'s, Fz_i⁰ the static ones), Fx_i the axle's
longitudinal force (``combined_slip``'s: M·a_x by the brake balance or the drive layout) and p the load exponent
(1: stiffness and peak in proportion to the load; tyres are usually 0.6-0.9). At a constant speed it is
``tire_saturation_axles`` exactly. The cornering stiffness an axle shows is k_i·s_i·D_i, its peak k_i·s_i·μ_i·Fz_i⁰.

Value syntax: ``load_sensitivity=MU_FRONT:MU_REAR:P`` (for example ``load_sensitivity=1.1:1.2:0.8``). Block-mean
form: the law solved at full rate (the compiled tyre model with each sample's loads, :func:`online_id.model.tyres.
_peaks`'s six-column form) and averaged. Fit: μ's and p. Filter form: the two μ's as extra states, as
``tire_saturation_axles``, the filters reading each sample's a_x; p is carried at its value (a constant of the law).
"""

from __future__ import annotations

import numpy as np

from online_id.effects.base import FitParameter, parse_number
from online_id.effects.combined_slip import CombinedSlip
from online_id.effects.tire_saturation import MU_FIT, _positive
from online_id.errors import OnlineIdError
from online_id.vehicle.parameters import MIN_LOAD_SHARE, axle_loads

#: The load exponent's fit: where it starts, its bounds and scale (0: the curve ignores the load; 1: in proportion).
EXPONENT_FIT = dict(initial=1.0, lower=0.0, upper=1.5, scale=0.5)


class LoadSensitivity(CombinedSlip):
    name = "load_sensitivity"
    syntax = ("MU_FRONT:MU_REAR:P: friction coefficient of each axle and the load exponent p of its whole curve"
              " (stiffness and peak ∝ Fz^p, shrunk by the friction ellipse's longitudinal share), e.g. 1.1:1.2:0.8")
    example = "1.1:1.2:0.8"
    summary = ("each axle's whole tyre curve scaled by (Fz_i/Fz_i⁰)^p·√(1 − (Fx_i/peak_i)²): cornering stiffness and"
               " peak follow the load moved by a_x less than linearly and shrink with the braking or driving force")
    refines = "combined_slip"
    held_online = ("load_exponent",)
    note = ("needs the run's longitudinal acceleration (logged, or dV/dt from the speed), the CG height hg and the"
            " brake balance and drive layout (vehicle file; 0.6 front and rear-wheel drive when not given)")

    @classmethod
    def fit_parameters(cls):
        return [FitParameter("mu_front", "-", **MU_FIT), FitParameter("mu_rear", "-", **MU_FIT),
                FitParameter("load_exponent", "-", **EXPONENT_FIT)]

    @classmethod
    def parse(cls, text):
        parts = text.split(":")
        if len(parts) != 3:
            raise OnlineIdError(f"--effect {cls.name}={text}: expected MU_FRONT:MU_REAR:P, e.g. {cls.example}")
        p = parse_number(cls.name, parts[2], "P")
        if not EXPONENT_FIT["lower"] <= p <= EXPONENT_FIT["upper"]:
            raise OnlineIdError(f"--effect {cls.name}: the load exponent P must be within"
                                f" {EXPONENT_FIT['lower']}-{EXPONENT_FIT['upper']}, got {parts[2]}")
        return cls(mu_front=_positive(cls.name, parts[0], "MU_FRONT"), mu_rear=_positive(cls.name, parts[1], "MU_REAR"),
                   load_exponent=p)

    def added_loads(self, known, loads, speed) -> np.ndarray:
        """The axle loads (n, 2) [N] with what else the law puts on the axles beside braking and traction's
        ``loads``: nothing here (``downforce``: c·Fz⁰·(V/50 m/s)²)."""
        return loads

    def axle_loads(self, known, longitudinal_acceleration=None, speed=None) -> np.ndarray:
        rows = super().axle_loads(known, longitudinal_acceleration)  # combined_slip's: Fz1, Fz2, Fx1, Fx2
        static = axle_loads(known)
        loads = np.maximum(self.added_loads(known, rows[:, :2], speed), MIN_LOAD_SHARE * static)
        factor = (loads / static) ** float(self.values["load_exponent"])
        return np.column_stack([np.broadcast_to(static, (len(loads), 2)), rows[:, 2:], factor])


#: The speed at which ``downforce``'s share is given [m/s] (180 km/h).
DOWNFORCE_REFERENCE_SPEED = 50.0
#: The downforce share's fit: where it starts, its bounds (−0.8: lift taking 80 % of the load at 180 km/h; 2: three
#: times the car's weight on its tyres) and scale.
DOWNFORCE_FIT = dict(initial=0.0, lower=-0.8, upper=2.0, scale=0.2)


class Downforce(LoadSensitivity):
    """``load_sensitivity`` on axle loads that also grow with the square of the speed (aerodynamic downforce):

        Fz_i = Fz_i⁰·(1 + c·(V / 50 m/s)²) ∓ M·a_x·hg/L

    c is the downforce at 180 km/h as a share of the static load (negative: lift), shared between the axles as the
    static load is. Through the load exponent the cornering stiffness and the peak grow with the speed: with the
    peak alone moving (``load_transfer``'s law) downforce shows only at the limit. A cornering stiffness that grows
    with speed for another reason (tyre temperature, a speed-dependent lag) looks the same to the data.

    Value syntax: ``downforce=MU_FRONT:MU_REAR:P:C`` (for example ``downforce=1.1:1.2:0.8:0.3``). Forms: those of
    ``load_sensitivity``, the loads read with each sample's speed; the filters carry p and c as constants."""

    name = "downforce"
    syntax = ("MU_FRONT:MU_REAR:P:C: friction coefficient of each axle, the load exponent p and the downforce c at"
              " 180 km/h as a share of the static load (negative: lift), e.g. 1.1:1.2:0.8:0.3")
    example = "1.1:1.2:0.8:0.3"
    summary = ("load_sensitivity on axle loads growing with the speed: Fz_i = Fz_i⁰·(1 + c·(V/50 m/s)²) ∓ M·a_x·hg/L"
               " (aerodynamic downforce, or lift for c < 0)")
    refines = "load_sensitivity"
    held_online = ("load_exponent", "downforce_share")

    @classmethod
    def fit_parameters(cls):
        return [*super().fit_parameters(), FitParameter("downforce_share", "-", **DOWNFORCE_FIT)]

    @classmethod
    def parse(cls, text):
        head, sep, tail = text.rpartition(":")
        if not sep:
            raise OnlineIdError(f"--effect {cls.name}={text}: expected MU_FRONT:MU_REAR:P:C, e.g. {cls.example}")
        c = parse_number(cls.name, tail, "C")
        if not DOWNFORCE_FIT["lower"] <= c <= DOWNFORCE_FIT["upper"]:
            raise OnlineIdError(f"--effect {cls.name}: the downforce share C must be within"
                                f" {DOWNFORCE_FIT['lower']} to {DOWNFORCE_FIT['upper']}, got {tail}")
        base = LoadSensitivity.parse(head)
        return cls(**base.values, downforce_share=c)

    def added_loads(self, known, loads, speed) -> np.ndarray:
        if speed is None:
            raise OnlineIdError(f"{self.name}: the axle loads follow the speed, and none was given")
        V = np.broadcast_to(np.asarray(speed, dtype=float).reshape(-1), (len(loads),))
        share = self.values["downforce_share"] * (V[:, None] / DOWNFORCE_REFERENCE_SPEED) ** 2
        return loads + share * axle_loads(known)
