"""Yaw-roll-sideslip-relaxation model of a car (Haro 2008, eqs 7-11; MODEL.md eqs 1-5).

State x = [r, β, φ, p, α1, α2] (rad/s, rad, rad, rad/s, rad, rad), input
u = δ, the front road-wheel angle [rad], speed V [m/s] scheduled sample by
sample.  Written as

    E(θ, V) ẋ = A(θ, V) x + B(V) δ

with the rows

    roll       (Mxx + ms h0²) ṗ − Mxz ṙ − ms h0 V (β̇ + r) = −Kro φ − Aro p
    yaw        Mzz ṙ − Mxz ṗ = −l1 D1 α1 + l2 D2 α2
    lateral    M V (β̇ + r) − ms h0 ṗ = −D1 α1 − D2 α2
    roll angle φ̇ = p
    front      b1 α̇1 = V β − V α1 + h1 p + l1 r − V ε1 φ − V δ
    rear       b2 α̇2 = V β − V α2 + h2 p − l2 r − V ε2 φ

so that the relaxation lengths sit in E and B does not depend on θ.  Measured
outputs, in :data:`OUTPUT_NAMES` order: yaw rate r, roll angle φ, roll rate p,
lateral acceleration a_y = V (β̇ + r) and the lateral velocity at the centre of gravity v_y = V β (an optical
sideslip sensor's or an INS's, issue 38; the model's small-angle kinematics, as in its slip angles).

Every function here is pure, with the argument order ``(x, u, theta, speed,
known)``.  ``theta`` is a :class:`~online_id.vehicle.parameters.Parameters`
or an array whose last axis holds the 8 values in
:data:`~online_id.vehicle.parameters.PARAMETER_NAMES` order; leading axes of
``theta`` (and of ``speed``) broadcast, so a population of parameter sets is
evaluated in one call.
"""

from __future__ import annotations

import numpy as np

from online_id.units import CHANNEL_UNITS
from online_id.vehicle.parameters import PARAMETER_NAMES, KnownParameters, Parameters

STATE_NAMES: tuple[str, ...] = ("yaw_rate", "sideslip", "roll_angle", "roll_rate", "slip_front", "slip_rear")
STATE_UNITS: tuple[str, ...] = ("rad/s", "rad", "rad", "rad/s", "rad", "rad")
OUTPUT_NAMES: tuple[str, ...] = ("yaw_rate", "roll_angle", "roll_rate", "lateral_acceleration", "lateral_velocity")
OUTPUT_UNITS: tuple[str, ...] = tuple(CHANNEL_UNITS[name] for name in OUTPUT_NAMES)
N_OUTPUTS = len(OUTPUT_NAMES)
#: The lateral velocity's row: the one output proportional to V (v_y = V β). The online filters work it per unit
#: speed, as the sideslip angle β = v_y / V (``outputs_from_continuous(..., per_unit_speed=True)``): their
#: outputs then do not depend on V (filters/local_model.py), and each sample's v_y is divided by its own V.
VY = 4

N_STATES = 6
N_PARAMS = len(PARAMETER_NAMES)
R, BETA, PHI, P, A1, A2 = range(N_STATES)
MZZ, MXX, D1, D2, ARO, KRO, B1, B2 = range(N_PARAMS)
#: Index of each output in the state where the output is a state, else None.
_OUTPUT_STATE = (R, PHI, P, None, BETA)


def theta_array(theta) -> np.ndarray:
    """``theta`` as a float array with last axis 8 (accepts :class:`Parameters`)."""
    if isinstance(theta, Parameters):
        return theta.to_vector()
    t = np.asarray(theta, dtype=float)
    if t.shape[-1:] != (N_PARAMS,):
        raise ValueError(f"theta must have last axis {N_PARAMS}, got shape {t.shape}")
    return t


def descriptor_matrices(theta, speed, known: KnownParameters):
    """E, A (shape (..., 6, 6)) and B (shape (..., 6)) of E ẋ = A x + B δ."""
    t = theta_array(theta)
    V = np.asarray(speed, dtype=float)
    shape = np.broadcast_shapes(t.shape[:-1], V.shape)
    t = np.broadcast_to(t, shape + (N_PARAMS,))
    V = np.broadcast_to(V, shape)
    k = known
    msh0 = k.ms * k.h0

    E = np.zeros(shape + (N_STATES, N_STATES))
    E[..., 0, R] = -k.Mxz
    E[..., 0, BETA] = -msh0 * V
    E[..., 0, P] = t[..., MXX] + msh0 * k.h0
    E[..., 1, R] = t[..., MZZ]
    E[..., 1, P] = -k.Mxz
    E[..., 2, BETA] = k.M * V
    E[..., 2, P] = -msh0
    E[..., 3, PHI] = 1.0
    E[..., 4, A1] = t[..., B1]
    E[..., 5, A2] = t[..., B2]

    A = np.zeros(shape + (N_STATES, N_STATES))
    A[..., 0, R] = msh0 * V
    A[..., 0, PHI] = -t[..., KRO]
    A[..., 0, P] = -t[..., ARO]
    A[..., 1, A1] = -k.l1 * t[..., D1]
    A[..., 1, A2] = k.l2 * t[..., D2]
    A[..., 2, R] = -k.M * V
    A[..., 2, A1] = -t[..., D1]
    A[..., 2, A2] = -t[..., D2]
    A[..., 3, P] = 1.0
    A[..., 4, R] = k.l1
    A[..., 4, BETA] = V
    A[..., 4, PHI] = -V * k.eps1
    A[..., 4, P] = k.h1
    A[..., 4, A1] = -V
    A[..., 5, R] = -k.l2
    A[..., 5, BETA] = V
    A[..., 5, PHI] = -V * k.eps2
    A[..., 5, P] = k.h2
    A[..., 5, A2] = -V

    B = np.zeros(shape + (N_STATES,))
    B[..., 4] = -V
    return E, A, B


def descriptor_parameter_derivatives(known: KnownParameters):
    """∂E/∂θ_i and ∂A/∂θ_i, each of shape (8, 6, 6); B does not depend on θ.

    E and A are affine in θ, so these are constant.
    """
    dE = np.zeros((N_PARAMS, N_STATES, N_STATES))
    dA = np.zeros((N_PARAMS, N_STATES, N_STATES))
    dE[MZZ, 1, R] = 1.0
    dE[MXX, 0, P] = 1.0
    dE[B1, 4, A1] = 1.0
    dE[B2, 5, A2] = 1.0
    dA[D1, 1, A1] = -known.l1
    dA[D1, 2, A1] = -1.0
    dA[D2, 1, A2] = known.l2
    dA[D2, 2, A2] = -1.0
    dA[ARO, 0, P] = -1.0
    dA[KRO, 0, PHI] = -1.0
    return dE, dA


def continuous_matrices(theta, speed, known: KnownParameters):
    """Ac = E⁻¹A (shape (..., 6, 6)) and Bc = E⁻¹B (shape (..., 6)): ẋ = Ac x + Bc δ."""
    E, A, B = descriptor_matrices(theta, speed, known)
    Ac = np.linalg.solve(E, A)
    Bc = np.linalg.solve(E, B[..., None])[..., 0]
    return Ac, Bc


def continuous_parameter_derivatives(theta, speed, known: KnownParameters):
    """∂Ac/∂θ_i (shape (..., 8, 6, 6)) and ∂Bc/∂θ_i (shape (..., 8, 6)), with Ac and Bc.

    From E Ac = A:  ∂Ac/∂θ_i = E⁻¹ (∂A/∂θ_i − ∂E/∂θ_i Ac), and likewise for Bc.
    Returns ``(Ac, Bc, dAc, dBc)``.
    """
    E, A, B = descriptor_matrices(theta, speed, known)
    Einv = np.linalg.inv(E)
    Ac = Einv @ A
    Bc = np.einsum("...ij,...j->...i", Einv, B)
    dE, dA = descriptor_parameter_derivatives(known)
    Einv_ = Einv[..., None, :, :]
    dAc = Einv_ @ (dA - dE @ Ac[..., None, :, :])
    dBc = -np.einsum("...ij,kjl,...l->...ki", Einv, dE, Bc)
    return Ac, Bc, dAc, dBc


def state_derivative(x, u, theta, speed, known: KnownParameters) -> np.ndarray:
    """ẋ = f(x, δ), shape (..., 6).  ``x`` has shape (..., 6), ``u`` is δ [rad]."""
    E, A, B = descriptor_matrices(theta, speed, known)
    rhs = np.einsum("...ij,...j->...i", A, x) + B * np.asarray(u, dtype=float)[..., None]
    return np.linalg.solve(E, rhs[..., None])[..., 0]


def state_jacobian(x, u, theta, speed, known: KnownParameters) -> np.ndarray:
    """∂f/∂x = Ac, shape (..., 6, 6) (the model is linear in the state)."""
    return continuous_matrices(theta, speed, known)[0]


def parameter_jacobian(x, u, theta, speed, known: KnownParameters) -> np.ndarray:
    """∂f/∂θ, shape (..., 6, 8): column i is ∂Ac/∂θ_i x + ∂Bc/∂θ_i δ."""
    _, _, dAc, dBc = continuous_parameter_derivatives(theta, speed, known)
    x = np.asarray(x, dtype=float)
    u = np.asarray(u, dtype=float)
    cols = np.einsum("...kij,...j->...ki", dAc, x) + dBc * u[..., None, None]
    return np.swapaxes(cols, -1, -2)


def output_matrices(theta, speed, known: KnownParameters):
    """C (shape (..., 5, 6)) and D (shape (..., 5)) of y = C x + D δ.

    Rows follow :data:`OUTPUT_NAMES`; the a_y row is V (Ac[β] + e_r), D is V·Bc[β]
    (zero for this model: δ reaches β̇ only through the slip states); the v_y row V e_β.
    """
    Ac, Bc = continuous_matrices(theta, speed, known)
    return outputs_from_continuous(Ac, Bc, speed)


def outputs_from_continuous(Ac, Bc, speed, per_unit_speed: bool = False):
    """C and D of :func:`output_matrices` from already computed Ac, Bc (saves a solve); ``per_unit_speed``: the
    lateral velocity's row per unit speed (e_β, the sideslip angle: the online filters', :data:`VY`)."""
    V = np.asarray(speed, dtype=float)
    shape = Ac.shape[:-2]
    C = np.zeros(shape + (len(OUTPUT_NAMES), N_STATES))
    for row, state in enumerate(_OUTPUT_STATE):
        if state is not None:
            C[..., row, state] = 1.0
    if not per_unit_speed:
        C[..., VY, BETA] = V
    C[..., 3, :] = V[..., None] * Ac[..., BETA, :]
    C[..., 3, R] += V
    D = np.zeros(shape + (len(OUTPUT_NAMES),))
    D[..., 3] = V * Bc[..., BETA]
    return C, D


def outputs(x, u, theta, speed, known: KnownParameters) -> np.ndarray:
    """Measured outputs [r, φ, p, a_y, v_y], shape (..., 5)."""
    C, D = output_matrices(theta, speed, known)
    return np.einsum("...ij,...j->...i", C, x) + D * np.asarray(u, dtype=float)[..., None]


def output_parameter_jacobian(x, u, theta, speed, known: KnownParameters) -> np.ndarray:
    """∂y/∂θ, shape (..., 5, 8).  Only a_y depends on θ: ∂a_y/∂θ = V ∂β̇/∂θ."""
    dfdtheta = parameter_jacobian(x, u, theta, speed, known)
    V = np.asarray(speed, dtype=float)
    J = np.zeros(dfdtheta.shape[:-2] + (len(OUTPUT_NAMES), N_PARAMS))
    J[..., 3, :] = V[..., None] * dfdtheta[..., BETA, :]
    return J


def steady_state(u, theta, speed, known: KnownParameters) -> np.ndarray:
    """Equilibrium state for a constant road-wheel angle δ: x = −Ac⁻¹ Bc δ."""
    Ac, Bc = continuous_matrices(theta, speed, known)
    return -np.linalg.solve(Ac, Bc[..., None])[..., 0] * np.asarray(u, dtype=float)[..., None]
