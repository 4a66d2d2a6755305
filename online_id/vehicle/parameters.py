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
}


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

    @property
    def wheelbase(self) -> float:
        """l1 + l2 [m]."""
        return self.l1 + self.l2


def axle_loads(known: KnownParameters) -> np.ndarray:
    """Static vertical loads on the front and rear axle [N] (2,)."""
    L = known.l1 + known.l2
    return known.M * G * np.array([known.l2 / L, known.l1 / L])


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
