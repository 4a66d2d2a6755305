"""Speed levels and the model's modal form at each: what makes simulation cheap when speed varies.

The model ẋ = Ac(θ, V) x + Bc(θ, V) u changes with speed V, so a simulation that takes the exact
zero-order-hold transition at every sample's speed needs one matrix exponential (or eigen-
decomposition) per sample. A run's speeds, though, cluster: 400 s of a race car between 16 and
61 m/s has only about ln(61/16)/tolerance distinct speeds to within a relative ``tolerance``.

:func:`speed_levels` groups the speeds of a run (sorted, not in time order) into levels no wider
than ``tolerance`` (relative), each level the mean of its members. Every sample is then simulated
at its level's speed: the speed used differs from the measured one by at most ``tolerance``
relative (1e-3 by default, a quarter of the spread of a race car's speed within one 0.1 s block),
and a constant speed is kept exactly. The matrices of the model are smooth in V (entries in V, 1/V
after E⁻¹), so the outputs move by O(tolerance) relative at most; the test against the per-sample
exact recursion bounds it.

:func:`modal_form` decomposes Ac = W Λ W⁻¹ once per level and per parameter set, all in one
batched LAPACK call, and gives the exact ZOH discretisation in modal coordinates:
z[k+1] = μ z[k] + b u[k], μ = exp(λ dt), b = φ₁(λ dt) dt W⁻¹ Bc with φ₁(s) = (eˢ − 1)/s.
A level whose eigenvectors are ill-conditioned (near-defective Ac) is flagged and its real Ad,
Bd come from the matrix exponential instead.

With an input that is not held over a sample (``intersample`` "linear" or "cubic",
:mod:`online_id.model.intersample`: the steering between two samples as the polynomial w in the normalised
time s), :func:`modal_form` also gives the exact step's input columns of the steering,

    x[k+1] = Ad x[k] + Γ w[k],   Γ_j = Re(W diag(T φ_j+1(λ T)) W⁻¹ Bc),   j = 0..3,

each mode's φ_j on its own (:func:`online_id.model.intersample.phi_functions`: a slow mode near the
critical speed loses no digits), Γ_0 = Bd the hold's column; an ill-conditioned level's Γ from the matrix
exponential of the augmented generator (:func:`online_id.model.intersample.input_columns`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import expm

from online_id.model import intersample as its
from online_id.model.lateral import BETA, N_STATES, descriptor_matrices, outputs_from_continuous
from online_id.vehicle.parameters import KnownParameters

#: Relative width of a speed level (see the module docstring for the error it brings).
SPEED_TOLERANCE = 1e-3
#: Eigenvector condition number above which the modal form is not trusted.
MAX_MODAL_CONDITION = 1e8
#: Below this |λ dt| the series 1 + s/2 + s²/6 replaces (eˢ − 1)/s (its cancellation error is then ~1e-16/s).
_PHI1_SERIES = 1e-6


def speed_levels(speed, tolerance: float = SPEED_TOLERANCE) -> tuple[np.ndarray, np.ndarray]:
    """Levels (L,) [m/s] and each sample's level index (n,) (see the module docstring)."""
    V = np.asarray(speed, dtype=float)
    order = np.argsort(V, kind="stable")
    sorted_v = V[order]
    group = np.empty(len(V), dtype=int)
    g, start = 0, sorted_v[0] if len(V) else 0.0
    for k, v in enumerate(sorted_v):  # sorted: one pass, a new level when the width would exceed tolerance
        if v - start > tolerance * abs(start):
            g, start = g + 1, v
        group[k] = g
    index = np.empty(len(V), dtype=int)
    index[order] = group
    counts = np.bincount(index)
    levels = np.bincount(index, weights=V) / counts
    return levels, index


def geometric_levels(speed, tolerance: float) -> tuple[np.ndarray, np.ndarray]:
    """Levels (L,) [m/s] and each sample's level index (n,): the speeds binned on a geometric grid of relative
    spacing ``tolerance`` (each level the centre of its members' range, so within ``tolerance``/2 relative of
    each; a constant speed is kept exactly). :func:`speed_levels` without its loop over the samples (a run
    simulated at 10 kHz has 600,000 of them a minute)."""
    V = np.asarray(speed, dtype=float)
    bins = np.floor(np.log(V / V.min()) / np.log1p(tolerance)).astype(np.int64)
    _, index = np.unique(bins, return_inverse=True)
    low = np.full(index.max() + 1, np.inf)
    high = np.full(index.max() + 1, -np.inf)
    np.minimum.at(low, index, V)
    np.maximum.at(high, index, V)
    return 0.5 * (low + high), index


def level_runs(index: np.ndarray) -> list[tuple[int, int, int]]:
    """(start, stop, level) of each stretch of consecutive samples at one level, in time order."""
    index = np.asarray(index)
    cuts = np.flatnonzero(np.diff(index)) + 1
    starts = np.concatenate([[0], cuts])
    stops = np.concatenate([cuts, [len(index)]])
    return [(int(a), int(b), int(index[a])) for a, b in zip(starts, stops)]


def input_matrices(theta, levels, known: KnownParameters, forces: bool = False):
    """Ac (P, L, 6, 6) and Bc (P, L, 6, m) with m = 1 (δ) or 3 (δ, w1, w2: extra axle forces [N],
    entering the yaw and lateral rows as l1·w1 − l2·w2 and w1 + w2), and C (P, L, 4, 6), D (P, L, 4, m)
    of the outputs [r, φ, p, a_y]. ``theta`` has shape (P, 8)."""
    theta = np.asarray(theta, dtype=float)
    E, A, B = descriptor_matrices(theta[:, None, :], np.asarray(levels, dtype=float)[None, :], known)
    G = B[..., None]
    if forces:
        G = np.concatenate([G, np.zeros(G.shape)[..., [0, 0]]], axis=-1)
        G[..., 1, 1], G[..., 1, 2] = known.l1, -known.l2
        G[..., 2, 1], G[..., 2, 2] = 1.0, 1.0
    Ac = np.linalg.solve(E, A)
    Bc = np.linalg.solve(E, G)
    C, D0 = outputs_from_continuous(Ac, Bc[..., 0], np.broadcast_to(levels, Ac.shape[:-2]))
    D = np.zeros(D0.shape + (Bc.shape[-1],))
    D[..., 0] = D0
    D[..., 3, :] = np.asarray(levels)[None, :, None] * Bc[..., BETA, :]  # a_y = V(β̇ + r): inputs reach β̇
    return Ac, Bc, C, D


def _inverse_or_nan(W: np.ndarray) -> np.ndarray:
    """Batched inverse; a singular matrix (a defective Ac) gives NaN instead of stopping the batch."""
    try:
        return np.linalg.inv(W)
    except np.linalg.LinAlgError:
        out = np.full(W.shape, np.nan, dtype=W.dtype)
        for idx in np.ndindex(W.shape[:-2]):
            try:
                out[idx] = np.linalg.inv(W[idx])
            except np.linalg.LinAlgError:
                pass
        return out


@dataclass
class ModalForm:
    """Exact ZOH model at each (parameter set, level), in modal coordinates where ``ok``.

    mu (P, L, 6) = exp(λ dt); W, Winv (P, L, 6, 6); b (P, L, 6, m) = W⁻¹ Bd (modal inputs);
    Ad (P, L, 6, 6), Bd (P, L, 6, m) real; C (P, L, 4, 6), D (P, L, 4, m); ok (P, L) bool;
    Gamma (P, L, 6, 4) real: the steering's input columns of the exact step for a steering polynomial w
    (module docstring), None for the hold (``intersample="hold"``, which needs Bd alone).
    """

    mu: np.ndarray
    W: np.ndarray
    Winv: np.ndarray
    b: np.ndarray
    Ad: np.ndarray
    Bd: np.ndarray
    C: np.ndarray
    D: np.ndarray
    ok: np.ndarray
    Gamma: np.ndarray | None = None


def modal_form(theta, levels, known: KnownParameters, dt: float, forces: bool = False,
               intersample: str = "hold") -> ModalForm:
    """The model of each parameter set (rows of ``theta``, shape (P, 8)) at each speed level; with an
    ``intersample`` other than the hold, the steering's input columns Γ too (module docstring)."""
    its.check_kind(intersample)
    Ac, Bc, C, D = input_matrices(theta, levels, known, forces)
    with np.errstate(all="ignore"):
        lam, W = np.linalg.eig(Ac)
        Winv = _inverse_or_nan(W)
        # ‖W‖_F ‖W⁻¹‖_F bounds the 2-norm condition number from above (and costs no SVD)
        cond = np.linalg.norm(W, axis=(-2, -1)) * np.linalg.norm(Winv, axis=(-2, -1))
        ok = np.isfinite(cond) & (cond < MAX_MODAL_CONDITION)
        Wsafe = np.where(ok[..., None, None], W, np.eye(N_STATES))
        Winv = np.where(ok[..., None, None], Winv, np.eye(N_STATES))
        s = lam * dt
        small = np.abs(s) < _PHI1_SERIES
        phi1 = np.where(small, 1.0 + s / 2 + s * s / 6, np.expm1(s) / np.where(small, 1.0, s))
        mu = np.exp(s)
        b = (phi1 * dt)[..., None] * (Winv @ Bc)
        Ad = ((Wsafe * mu[..., None, :]) @ Winv).real
        Bd = (Wsafe @ b).real
    if not ok.all():
        bad = ~ok
        n, m = N_STATES, Bc.shape[-1]
        aug = np.zeros((int(bad.sum()), n + m, n + m))
        aug[:, :n, :n] = Ac[bad] * dt
        aug[:, :n, n:] = Bc[bad] * dt
        Phi = expm(aug)
        Ad[bad], Bd[bad] = Phi[:, :n, :n], Phi[:, :n, n:]
    Gamma = None if intersample == "hold" else _input_columns(lam, Wsafe, Winv, Ac, Bc[..., 0], Bd[..., 0], ok, dt)
    return ModalForm(mu=mu, W=Wsafe, Winv=Winv, b=b, Ad=Ad, Bd=Bd, C=C, D=D, ok=ok, Gamma=Gamma)


def _input_columns(lam, W, Winv, Ac, Bc, Bd, ok, dt: float) -> np.ndarray:
    """Γ (P, L, 6, 4) of the steering (module docstring): mode by mode where the eigenvectors are trusted
    (:func:`online_id.model.intersample.modal_input_columns`), from the augmented generator's exponential
    elsewhere; Γ_0 is Bd itself (the hold's column, so a held input steps exactly as the hold does)."""
    with np.errstate(all="ignore"):
        Gamma = its.modal_input_columns(np.where(ok[..., None], lam, 0.0), W, Winv, Bc, dt)
    if not ok.all():
        Gamma[~ok] = its.input_columns(Ac[~ok], Bc[~ok], dt)
    Gamma[..., 0] = Bd
    return Gamma
