"""Exact zero-order-hold discretisation of the lateral model, and its parameter sensitivity.

For a sample period dt with δ held constant over the period,

    x[k+1] = Ad x[k] + Bd δ[k],   [[Ad, Bd], [0, 1]] = expm([[Ac, Bc], [0, 0]] dt).

The derivative of the transition with respect to θ_i uses Van Loan's block
identity: the top-right block of expm([[G, dG_i], [0, G]]) is the Fréchet
derivative of expm at G in the direction dG_i, exact up to round-off.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import expm

from online_id.model.lateral import (
    N_STATES,
    continuous_matrices,
    continuous_parameter_derivatives,
    outputs_from_continuous,
)
from online_id.vehicle.parameters import KnownParameters


def _augmented(Ac, Bc, dt):
    n = N_STATES
    G = np.zeros(Ac.shape[:-2] + (n + 1, n + 1))
    G[..., :n, :n] = Ac * dt
    G[..., :n, n] = Bc * dt
    return G


def discretise(theta, speed, known: KnownParameters, dt: float):
    """Ad (shape (..., 6, 6)) and Bd (shape (..., 6)) for sample period ``dt`` [s]."""
    Ac, Bc = continuous_matrices(theta, speed, known)
    return discretise_continuous(Ac, Bc, dt)


def discretise_continuous(Ac, Bc, dt: float):
    """ZOH discretisation of given continuous matrices (batched over leading axes)."""
    Phi = expm(_augmented(Ac, Bc, dt))
    return Phi[..., :N_STATES, :N_STATES], Phi[..., :N_STATES, N_STATES]


@dataclass(frozen=True)
class Linearisation:
    """Everything a filter needs about the model at one parameter set, speed and sample period.

    Continuous: Ac (6, 6), Bc (6,), dAc (8, 6, 6), dBc (8, 6) (derivatives with respect to θ).
    Discrete (ZOH over ``dt``): Ad, Bd, dAd, dBd, same shapes.
    Outputs y = C x + D δ: C (4, 6), D (4,).
    """

    theta: np.ndarray
    speed: float
    dt: float
    Ac: np.ndarray
    Bc: np.ndarray
    dAc: np.ndarray
    dBc: np.ndarray
    Ad: np.ndarray
    Bd: np.ndarray
    dAd: np.ndarray
    dBd: np.ndarray
    C: np.ndarray
    D: np.ndarray


def linearise(theta, speed: float, known: KnownParameters, dt: float) -> Linearisation:
    """Continuous and discrete matrices with their θ-derivatives for one parameter set and speed."""
    Ac, Bc, dAc, dBc = continuous_parameter_derivatives(theta, speed, known)
    if Ac.ndim != 2:
        raise ValueError("linearise takes one parameter set and one speed")
    n = N_STATES + 1
    G = _augmented(Ac, Bc, dt)
    dG = _augmented(dAc, dBc, dt)  # (8, 7, 7)
    big = np.zeros((dG.shape[0], 2 * n, 2 * n))
    big[:, :n, :n] = G
    big[:, n:, n:] = G
    big[:, :n, n:] = dG
    Phi = expm(big)
    dPhi = Phi[:, :n, n:]
    Phi0 = Phi[0, :n, :n]
    C, D = outputs_from_continuous(Ac, Bc, np.asarray(speed, dtype=float))
    return Linearisation(
        theta=np.array(theta.to_vector() if hasattr(theta, "to_vector") else theta, dtype=float),
        speed=float(speed), dt=float(dt), Ac=Ac, Bc=Bc, dAc=dAc, dBc=dBc,
        Ad=Phi0[:N_STATES, :N_STATES], Bd=Phi0[:N_STATES, N_STATES],
        dAd=dPhi[:, :N_STATES, :N_STATES], dBd=dPhi[:, :N_STATES, N_STATES], C=C, D=D,
    )


def discretise_with_sensitivity(theta, speed, known: KnownParameters, dt: float):
    """Ad, Bd and their derivatives with respect to θ, for one parameter set and speed.

    Returns ``(Ad, Bd, dAd, dBd)`` with shapes (6, 6), (6,), (8, 6, 6), (8, 6):
    dAd[i] = ∂Ad/∂θ_i, dBd[i] = ∂Bd/∂θ_i.
    """
    lin = linearise(theta, speed, known, dt)
    return lin.Ad, lin.Bd, lin.dAd, lin.dBd
