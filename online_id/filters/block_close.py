"""A block's close in compiled calls (numba): the covariance's predict, the block's covariances and the Joseph
correction of :mod:`online_id.filters.block_update`, each one call instead of a dozen numpy calls.

At a logger's rate (100 Hz) the EKF corrects every 5 samples (``MAX_BLOCK_S``, 50 ms): 1,199 corrections a
minute, each of which cost a few hundred microseconds of numpy calls on 14 × 14 matrices whose arithmetic is
a few microseconds (issue 40 item 5). These functions are the same expressions, in the same order: numba's
matrix products and solve call the BLAS and LAPACK routines numpy calls (dgemm, dgesv), so the numbers are
numpy's, bit for bit (``tests/test_block_close.py`` compares them).

Compiled at first use and cached on disk (online_id/util/jit.py).
"""

from __future__ import annotations

import numpy as np

from online_id.util.jit import cached_njit


@cached_njit()
def predict_covariance(F, P, q):  # pragma: no cover -- compiled
    """P ← F P Fᵀ + Q over a block: ``F`` (n, n) the block's chained Jacobian, ``P`` (n, n), ``q`` (n,) the
    diagonal of Q (filterpy's ``predict``, ``dot(F, P).dot(F.T) + Q``, with Q = diag(q))."""
    return (F @ P) @ F.T + np.diag(q)


@cached_njit()
def block_covariances(Hbar, C_states, q, P_start, F_block, R_over_n):  # pragma: no cover -- compiled
    """C = cov(z_end, ȳ) (n, m) and S = cov(ȳ) (m, m) of a block (filters/block_update.py's docstring):
    ``Hbar`` (m, n), ``C_states`` (m, 6) the outputs' rows to the model states, ``q`` (n,) the observed share
    of Q, ``P_start`` (n, n), ``F_block`` (n, n), ``R_over_n`` (m,)."""
    He = Hbar.copy()
    He[:, :C_states.shape[1]] = C_states
    QHe = q.reshape(-1, 1) * He.T
    PHt = P_start @ Hbar.T
    S = Hbar @ PHt + He @ QHe + np.diag(R_over_n)
    return F_block @ PHt + QHe, S


@cached_njit()
def joseph_covariance(P, C, S):  # pragma: no cover -- compiled
    """The gain K = C S⁻¹ (n, m) and the covariance (n, n) corrected by a block whose ``C`` (n, m) and ``S``
    (m, m) are given: P − K Cᵀ − C Kᵀ + K S Kᵀ, symmetrised. (The mean's K (z − ẑ) is left to numpy: its
    matrix-vector product sums in another order than numba's; K is returned in Fortran order, as numpy's
    ``solve(S, C.T).T`` is, so that numpy's product is the one it was.)"""
    K = np.linalg.solve(S, C.T).T
    KC = K @ C.T
    P = P - KC - KC.T + K @ S @ K.T
    return np.asfortranarray(K), 0.5 * (P + P.T)


@cached_njit()
def all_finite(C, S):  # pragma: no cover -- compiled
    """Whether every element of ``C`` and ``S`` is finite (numba's solve raises on a NaN or an inf; numpy's
    returns NaNs, which the filter's health check then finds: :func:`joseph_covariance` is called only here)."""
    for a in range(C.shape[0]):
        for b in range(C.shape[1]):
            if not np.isfinite(C[a, b]):
                return False
    for a in range(S.shape[0]):
        for b in range(S.shape[1]):
            if not np.isfinite(S[a, b]):
                return False
    return True


def compile_now(n: int) -> None:
    """Compile (or load from the disk cache) the functions above now, for an ``n``-long augmented state: a live
    run must not stall at its first correction."""
    P, F, q = np.eye(n), np.eye(n), np.ones(n)
    H, S = np.ones((1, n)), np.ones((1, 1))
    predict_covariance(F, P, q)
    C, S = block_covariances(H, H[:, :min(n, 6)].copy(), q, P, F, np.ones(1))
    all_finite(C, S)
    joseph_covariance(P, C, S)
