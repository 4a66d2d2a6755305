"""Full-rate simulation with extra axle forces: the base model plus a force law of the slip angles.

The base model's tyre forces are F_i = −D_i·α_i. An unmodelled force law (for example a tyre
that saturates, :mod:`online_id.effects.tire_saturation`) is written as the linear force plus a
correction w_i(α_i) = F_i(α_i) + D_i·α_i that enters the yaw and lateral equations (eqs 2-3)
as a generalised force:

    E ẋ = A x + B δ + G w,   G[yaw] = [l1, −l2],  G[lateral] = [1, 1].

Discretised with w held over each sample (like δ), x[k+1] = Ad x[k] + Bd δ[k] + Gd w(x[k]).
:func:`simulate_with_forces` solves that recursion exactly as written, either by a plain loop
(``method="loop"``, the reference) or by fixed-point iteration on whole signals in modal form
(``method="picard"``, tens of times faster, used for fitting), which converges while the force
correction is a moderate fraction of the linear force.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy.linalg import expm
from scipy.signal import lfilter

from online_id.errors import OnlineIdError
from online_id.model.lateral import A1, A2, BETA, N_STATES, descriptor_matrices, outputs_from_continuous
from online_id.sim.fast import speed_segments
from online_id.vehicle.parameters import KnownParameters

#: A force law: slip angles (..., 2) [rad] → correction w (..., 2) [N] to the linear forces −D·α.
ForceLaw = Callable[[np.ndarray], np.ndarray]


def _matrices(theta, V: float, known: KnownParameters, dt: float):
    """Ad (6,6), Bd (6,3) for inputs [δ, w1, w2], and output matrices C (4,6), D (4,3)."""
    E, A, B = descriptor_matrices(np.asarray(theta, dtype=float), np.array(V), known)
    G = np.zeros((N_STATES, 3))
    G[:, 0] = B
    G[1, 1:] = known.l1, -known.l2
    G[2, 1:] = 1.0, 1.0
    Ac = np.linalg.solve(E, A)
    Bc = np.linalg.solve(E, G)
    aug = np.zeros((N_STATES + 3, N_STATES + 3))
    aug[:N_STATES, :N_STATES] = Ac * dt
    aug[:N_STATES, N_STATES:] = Bc * dt
    Phi = expm(aug)
    C, D0 = outputs_from_continuous(Ac, Bc[:, 0], np.array(V))
    D = np.zeros((4, 3))
    D[:, 0] = D0
    D[3, :] = V * Bc[BETA, :]  # a_y = V(β̇ + r): forces reach β̇ directly
    return Phi[:N_STATES, :N_STATES], Phi[:N_STATES, N_STATES:], C, D


def _modal_states(Ad, Bd, u, x0) -> tuple[np.ndarray, np.ndarray]:
    """States x[0..n-1] (x[0] = x0) and the state after the last input, for inputs u (n, m)."""
    lam, W = np.linalg.eig(Ad)
    if np.linalg.cond(W) > 1e8:
        x = x0.copy()
        states = np.empty((len(u), N_STATES))
        for k in range(len(u)):
            states[k] = x
            x = Ad @ x + Bd @ u[k]
        return states, x
    Winv = np.linalg.inv(W)
    v = u @ (Winv @ Bd).T  # (n, 6) complex
    z0 = Winv @ x0
    Z = np.empty((len(u), N_STATES), dtype=complex)
    z_end = np.empty(N_STATES, dtype=complex)
    for i in range(N_STATES):
        y, _ = lfilter([1.0], [1.0, -lam[i]], v[:, i], zi=[lam[i] * z0[i]])
        Z[0, i] = z0[i]
        Z[1:, i] = y[:-1]
        z_end[i] = y[-1]
    return (Z @ W.T).real, (W @ z_end).real


def simulate_with_forces(theta, known: KnownParameters, steering_wheel_angle, speed, dt: float,
                         force_law: ForceLaw | None = None, method: str = "picard", tol: float = 1e-9,
                         max_iterations: int = 200, warm: dict | None = None) -> tuple[np.ndarray, np.ndarray]:
    """States (N, 6) and noise-free outputs (N, 4) with an extra force law (None: the base model).

    ``speed`` is a scalar or one value per sample [m/s] (taken piecewise constant, as in
    :class:`~online_id.sim.fast.BlockSimulator`). ``warm``, a dict kept by the caller across calls
    with nearby parameters (a fit), starts each fixed-point iteration from the last forces.
    """
    dH = np.asarray(steering_wheel_angle, dtype=float)
    n = len(dH)
    V = np.broadcast_to(np.asarray(speed, dtype=float), (n,))
    delta = dH / known.steering_ratio
    states = np.empty((n, N_STATES))
    outputs = np.empty((n, 4))
    x = np.zeros(N_STATES)
    for a, b, v in speed_segments(V):
        Ad, Bd, C, D = _matrices(theta, v, known, dt)
        u = np.zeros((b - a, 3))
        u[:, 0] = delta[a:b]
        if force_law is None:
            states[a:b], x = _modal_states(Ad, Bd, u, x)
        elif method == "loop":
            for k in range(b - a):
                states[a + k] = x
                u[k, 1:] = force_law(x[[A1, A2]])
                x = Ad @ x + Bd @ u[k]
        elif method == "picard":
            if warm is not None and warm.get(a) is not None and len(warm[a]) == b - a:
                u[:, 1:] = warm[a]
            x = _picard(Ad, Bd, u, x, force_law, tol, max_iterations, states[a:b])
            if warm is not None:
                warm[a] = u[:, 1:].copy()
        else:
            raise ValueError(f"unknown method {method!r}; choose loop or picard")
        outputs[a:b] = states[a:b] @ C.T + u @ D.T
    return states, outputs


def _picard(Ad, Bd, u, x0, force_law, tol, max_iterations, out_states) -> np.ndarray:
    """Fixed point of w = force_law(α(w)) on the whole segment; fills out_states, returns x_end."""
    scale = max(np.max(np.abs(u[:, 1:])), 1.0) if np.any(u[:, 1:]) else None
    for _ in range(max_iterations):
        states, x_end = _modal_states(Ad, Bd, u, x0)
        w = force_law(states[:, [A1, A2]])
        change = np.max(np.abs(w - u[:, 1:])) if len(w) else 0.0
        u[:, 1:] = w
        if scale is None:
            scale = max(np.max(np.abs(w)), 1.0)
        if change <= tol * scale:
            states, x_end = _modal_states(Ad, Bd, u, x0)
            out_states[:] = states
            return x_end
        if not np.all(np.isfinite(w)):
            break
    raise OnlineIdError("the force law did not converge (the tyres are too far into saturation for this"
                        " simulation); use method='loop'")
