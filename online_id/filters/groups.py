"""A group of samples of a linear time-varying recursion in a few matrix products (pure functions).

For the samples j = 1..m of a group,

    x_j = Ad_j x_j-1 + b_j,                     (the mean; b_j = Γ_j w_j, the step's input, Bd_j δ_j for the hold)
    F_j = Ad_j F_j-1 + [0 | J_j],               (the chained Jacobian ∂x_j/∂(augmented state at j = 0))

with J_j the sensitivity columns of step j to the constant states (the parameters, whatever their
number). With the transitions Φ(j, i) = Ad_j ⋯ Ad_i+1 (Φ(i, i) = I) both unroll to

    x_j = Φ(j, 0) x_0 + Σ_{i=1..j} Φ(j, i) b_i,
    F_j = Φ(j, 0) F_0 + [0 | Σ_{i=1..j} Φ(j, i) J_i],

i.e. with the stacked first column A = [Φ(1, 0); …; Φ(m, 0)] (mn × n) and the block lower-triangular
T (mn × mn, block (j, i) = Φ(j, i) for i ≤ j), X = A x_0 + T b and F = A F_0 + [0 | T J]: two matrix
products for the whole group instead of 2m small ones in a Python loop.

:func:`transition_table` builds A and T for any Ad_j (speed and sample period may change at every
sample) block row by block row: [Φ(j, 0) … Φ(j, j − 1)] = Ad_j [Φ(j − 1, 0) … Φ(j − 1, j − 1)], one product
per sample (measured 30 µs against 106 µs for doubling with index arrays at m = 20). When every Ad_j is
the same, :func:`constant_transition_table` takes powers of Ad instead (Φ(j, i) = Ad^(j-i), a
block-Toeplitz T).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

# the one-period groups' recursion lives beside the block close that calls it (numba caches a compiled function
# with its own file only): it is this module's as before
from online_id.filters.block_close import recurse_group  # noqa: F401


@lru_cache(maxsize=64)
def _toeplitz_index(m: int) -> np.ndarray:
    """(m, m) index into [0, I, Ad, Ad², …]: power a − b + 1 on and below the diagonal, 0 (zero) above."""
    a = np.arange(m)
    return np.where(a[:, None] >= a[None, :], a[:, None] - a[None, :] + 1, 0)


def transition_table(Ad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A (mn, n) and T (mn, mn) (module docstring) for the per-sample transitions ``Ad`` (m, n, n).

    Row by row: the j-th block row [Φ(j, 0) | Φ(j, 1) … Φ(j, j − 1)] is Ad_j times the (j − 1)-th, and
    Φ(j, j) = I; one (n × n)·(n × nj) product per sample (the table is lower block-triangular, so no work
    is spent above the diagonal).
    """
    m, n, _ = Ad.shape
    table = np.zeros((m * n, n + m * n))  # [A | T]
    eye = np.eye(n)
    table[:n, :n] = Ad[0]
    table[:n, n:2 * n] = eye
    for r in range(1, m):  # block row r is sample j = r + 1, and Ad[r] = Ad_j = Φ(j, j − 1)
        width = n * (r + 1)  # A's block and T's first r blocks
        np.matmul(Ad[r], table[(r - 1) * n:r * n, :width], out=table[r * n:(r + 1) * n, :width])
        table[r * n:(r + 1) * n, width:width + n] = eye
    return table[:, :n], table[:, n:]


def constant_transition_table(Ad: np.ndarray, m: int) -> tuple[np.ndarray, np.ndarray]:
    """A and T of :func:`transition_table` when all m transitions equal ``Ad`` (n, n): powers by doubling."""
    n = Ad.shape[0]
    powers = np.empty((m + 1, n, n))  # I, Ad, Ad², …
    powers[0] = np.eye(n)
    powers[1] = Ad
    k = 1
    while k < m:  # [Ad^(k+1), …, Ad^(k+j)] = Ad^k [Ad, …, Ad^j]
        j = min(k, m - k)
        np.matmul(powers[k], powers[1:j + 1], out=powers[k + 1:k + j + 1])
        k += j
    blocks = np.concatenate([np.zeros((1, n, n)), powers[:-1]])  # 0, I, Ad, …
    T = blocks[_toeplitz_index(m)].transpose(0, 2, 1, 3).reshape(m * n, m * n)
    return powers[1:].reshape(m * n, n), T


def propagate_mean(A: np.ndarray, T: np.ndarray, x0: np.ndarray, inputs: np.ndarray) -> np.ndarray:
    """X (m + 1, n): X[0] = x0, X[j] = x_j, for the per-sample inputs b_j ``inputs`` (m, n)."""
    m, n = inputs.shape
    X = np.empty((m + 1, n))
    X[0] = x0
    X[1:] = (A @ x0 + T @ inputs.reshape(m * n)).reshape(m, n)
    return X


def chain_jacobians(A: np.ndarray, T: np.ndarray, F0: np.ndarray, columns: np.ndarray) -> np.ndarray:
    """F (m + 1, n, N): F[0] = F0 (n, N), F[j] = ∂x_j/∂(augmented state at the start).

    ``columns`` (m, n, P): J_j, the step's sensitivity to the last P of the N augmented states (the
    constant ones); the first N − P are the n model states themselves (N − P = n).
    """
    m, n, P = columns.shape
    F = np.empty((m + 1,) + F0.shape)
    F[0] = F0
    Fg = F[1:].reshape(m * n, F0.shape[1])
    Fg[:] = A @ F0
    Fg[:, -P:] += T @ columns.reshape(m * n, P)
    return F
