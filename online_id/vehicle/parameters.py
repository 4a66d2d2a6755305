"""Parameter sets of the yaw-roll-sideslip-relaxation model, with names and units.

Two frozen dataclasses, SI units inside:

* :class:`KnownParameters`: what the constructor gives and we do not estimate
  (Haro 2008, Table 2), plus the steering ratio.
* :class:`Parameters`: the 8 estimated parameters, named with the papers'
  symbols (Mzz, Mxx, D1, D2, Aro, Kro, b1, b2) so results read against
  Tables 3, 5 and 6.

Filters and optimisers see plain vectors: use :meth:`Parameters.to_vector` and
:meth:`Parameters.from_vector` at that boundary, in the order of
:data:`PARAMETER_NAMES`.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields

import numpy as np

from online_id.units import G

#: The estimated parameters, in vector order.
PARAMETER_NAMES: tuple[str, ...] = ("Mzz", "Mxx", "D1", "D2", "Aro", "Kro", "b1", "b2")

#: SI unit of each estimated parameter.
PARAMETER_UNITS: dict[str, str] = {
    "Mzz": "kg·m²",
    "Mxx": "kg·m²",
    "D1": "N/rad",
    "D2": "N/rad",
    "Aro": "N·m·s/rad",
    "Kro": "N·m/rad",
    "b1": "m",
    "b2": "m",
}

#: What each estimated parameter is.
PARAMETER_DESCRIPTIONS: dict[str, str] = {
    "Mzz": "yaw moment of inertia",
    "Mxx": "sprung-mass roll inertia",
    "D1": "front cornering stiffness (axle)",
    "D2": "rear cornering stiffness (axle)",
    "Aro": "roll damping",
    "Kro": "roll stiffness (effective)",
    "b1": "front tyre relaxation length",
    "b2": "rear tyre relaxation length",
}

#: Unit of each known parameter.
KNOWN_UNITS: dict[str, str] = {
    "M": "kg",
    "ms": "kg",
    "Mxz": "kg·m²",
    "h0": "m",
    "h1": "m",
    "h2": "m",
    "hg": "m",
    "l1": "m",
    "l2": "m",
    "eps1": "-",
    "eps2": "-",
    "steering_ratio": "-",
    "brake_front_share": "-",
    "drive_front_share": "-",
}


#: The brake balance and the drive layout a vehicle file need not give (KnownParameters): most cars brake 55-70 %
#: on the front axle; the drive default is rear-wheel drive (a front-wheel-drive car's file says 1).
DEFAULT_BRAKE_FRONT_SHARE = 0.6
DEFAULT_DRIVE_FRONT_SHARE = 0.0
#: The known constants a vehicle file may leave out (their defaults above).
OPTIONAL_KNOWN = ("brake_front_share", "drive_front_share")


@dataclass(frozen=True)
class KnownParameters:
    """Vehicle constants taken as known (Haro 2008, Table 2), SI units.

    Attributes
    ----------
    M : total mass [kg]
    ms : sprung mass [kg]
    Mxz : roll-yaw product of inertia [kg·m²]
    h0 : distance from roll axis to centre of gravity [m]
    h1, h2 : front / rear roll-centre height [m]
    hg : centre of gravity above ground [m]
    l1, l2 : distance from centre of gravity to front / rear axle [m]
    eps1, eps2 : front / rear roll-steer coefficient [-]
    steering_ratio : steering-wheel angle over road-wheel angle [-]
    brake_front_share : the front axle's share of the braking force (the brake balance) [-]; optional in a vehicle
        file, :data:`DEFAULT_BRAKE_FRONT_SHARE` when not given (only ``combined_slip`` reads it)
    drive_front_share : the front axle's share of the driving force [-]: 0 rear-wheel drive, 1 front-wheel drive;
        optional, :data:`DEFAULT_DRIVE_FRONT_SHARE` (only ``combined_slip`` reads it)
    """

    M: float
    ms: float
    Mxz: float
    h0: float
    h1: float
    h2: float
    hg: float
    l1: float
    l2: float
    eps1: float
    eps2: float
    steering_ratio: float = 16.0
    brake_front_share: float = DEFAULT_BRAKE_FRONT_SHARE
    drive_front_share: float = DEFAULT_DRIVE_FRONT_SHARE

    @property
    def wheelbase(self) -> float:
        """l1 + l2 [m]."""
        return self.l1 + self.l2


def axle_loads(known: KnownParameters) -> np.ndarray:
    """Static vertical loads on the front and rear axle [N] (2,)."""
    L = known.l1 + known.l2
    return known.M * G * np.array([known.l2 / L, known.l1 / L])


#: The least share of its static load an axle keeps under load transfer (:func:`axle_loads_at`): below it the
#: axle is lifting, which no lateral model here describes; the load is held there rather than going to zero.
MIN_LOAD_SHARE = 0.05


def axle_loads_at(known: KnownParameters, longitudinal_acceleration) -> np.ndarray:
    """Axle loads moved by braking and traction [N] (n, 2): Fz1,2 = M·(g·l2,1 ∓ a_x·hg)/L, a_x [m/s²] (n,) the
    longitudinal acceleration at the centre of gravity (positive forward: traction unloads the front), hg the
    CG's height. Each load at least :data:`MIN_LOAD_SHARE` of its static value."""
    ax = np.asarray(longitudinal_acceleration, dtype=float).reshape(-1)
    L = known.l1 + known.l2
    static = axle_loads(known)
    moved = known.M * ax * known.hg / L
    loads = np.column_stack([static[0] - moved, static[1] + moved])
    return np.maximum(loads, MIN_LOAD_SHARE * static)


@dataclass(frozen=True)
class Parameters:
    """The 8 estimated parameters, SI units (see :data:`PARAMETER_UNITS`)."""

    Mzz: float
    Mxx: float
    D1: float
    D2: float
    Aro: float
    Kro: float
    b1: float
    b2: float

    def to_vector(self) -> np.ndarray:
        """Values as a float array of shape (8,), in :data:`PARAMETER_NAMES` order."""
        return np.array([getattr(self, n) for n in PARAMETER_NAMES], dtype=float)

    @classmethod
    def from_vector(cls, vector) -> Parameters:
        """Inverse of :meth:`to_vector`; ``vector`` has shape (8,)."""
        v = np.asarray(vector, dtype=float).reshape(-1)
        if v.shape != (len(PARAMETER_NAMES),):
            raise ValueError(f"expected {len(PARAMETER_NAMES)} parameter values, got shape {v.shape}")
        return cls(**{n: float(x) for n, x in zip(PARAMETER_NAMES, v)})

    def to_dict(self) -> dict[str, float]:
        return asdict(self)

    def scaled(self, factor) -> Parameters:
        """Every parameter multiplied by ``factor`` (a scalar or an (8,) array)."""
        return Parameters.from_vector(self.to_vector() * np.asarray(factor, dtype=float))


assert tuple(f.name for f in fields(Parameters)) == PARAMETER_NAMES
