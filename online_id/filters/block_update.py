"""The correction of a block from its means: the arithmetic the EKF and the tyre EKF share.

A block's mean measurement is compared with its mean prediction through H̄, its outputs' sensitivity to the
block-start state (filters/ekf.py's docstring derives it):

    S = H̄ P_start H̄ᵀ + H_e (w Q) H_eᵀ + R/n,   C = F P_start H̄ᵀ + (w Q) H_eᵀ,   K = C S⁻¹,
    z_end ← z_end + K (ȳ − ŷ),   P ← P − K Cᵀ − C Kᵀ + K S Kᵀ   (Joseph's form: right for any K),

with w Q the share of the block's process noise its observations saw and H_e the outputs' sensitivity to the
block-end state (the model states' output rows C, the parameters' H̄ columns).
"""

from __future__ import annotations

import numpy as np

from online_id.filters import block_close
from online_id.model.lateral import N_STATES


def observed_process_noise(q: np.ndarray, gap_variance, gap_at: int | None, observed_at: list,
                           block_samples: int) -> np.ndarray:
    """The share of the block's process noise ``q`` (its diagonal) the observations saw: each observation a sample
    into the block sees about that sample's share of it; a long gap's state variance (``gap_variance``, arrived
    before the ``gap_at``-th observation) is seen whole by every observation after the gap."""
    if gap_at is None and type(gap_variance) is float and gap_variance == 0.0:  # no long gap: the usual case
        # (a sum of integer counts is exact in any order: np.mean's number, without its overhead)
        return q * (sum(observed_at) / len(observed_at) / max(block_samples, 1))
    q = q.copy()
    q[:N_STATES] -= gap_variance
    q *= np.mean(observed_at) / max(block_samples, 1)
    if gap_at is not None:
        q[:N_STATES] += gap_variance * (1 - gap_at / len(observed_at))
    return q


def block_covariances(Hbar: np.ndarray, C_states: np.ndarray, q: np.ndarray, P_start: np.ndarray,
                      F_block: np.ndarray, R_over_n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """C = cov(z_end, ȳ) and S = cov(ȳ) of a block (module docstring): ``Hbar`` (m, n) the mean sensitivity to the
    block-start state, ``C_states`` (m, 6) the outputs' rows to the model states, ``q`` (n,) the observed share of
    Q, ``R_over_n`` (m,) each channel's noise variance over its sample count."""
    return block_close.block_covariances(Hbar, C_states, q, P_start, F_block, R_over_n)


def joseph_update(x: np.ndarray, P: np.ndarray, block: tuple, keep: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The mean and covariance corrected by a block ``(z, ẑ, C, S)`` on the channels ``keep`` (module docstring)."""
    z, zp, C, S = block
    if not keep.all():
        # (C's columns as a C-ordered copy: numpy gives them F-ordered, and the compiled calls below would be
        # compiled a second time for that layout)
        z, zp, C, S = z[keep], zp[keep], np.ascontiguousarray(C[:, keep]), S[np.ix_(keep, keep)]
    if block_close.all_finite(C, S):
        try:
            K, P_new = block_close.joseph_covariance(P, C, S)
            return x + K @ (z - zp), P_new
        except np.linalg.LinAlgError:  # a singular S: numpy's solve below raises it with numpy's words, as before
            pass
    # numpy's arithmetic, the compiled call's reference: also where numba's solve would refuse a NaN or an inf
    # that numpy's carries on to the filter's health check (filters/base.py)
    K = np.linalg.solve(S, C.T).T
    KC = K @ C.T
    P = P - KC - KC.T + K @ S @ K.T
    return x + K @ (z - zp), 0.5 * (P + P.T)
