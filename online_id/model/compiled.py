"""A linearisation point's arithmetic in compiled loops (numba), for :mod:`online_id.model.discretise`.

A point of the EKF (a new eigen-decomposition whenever the parameters or the speed move past their
steps) is a few hundred floating-point operations on 7 × 7 matrices spread over about 60 numpy calls:
on a weakly excited log, where the parameters move at every correction (the RAV4's), the calls' own
overhead was a fifth of the filter's time. These functions do the same arithmetic in one call each;
:func:`~online_id.model.discretise.derivative_blocks` and
:func:`~online_id.model.discretise.single_spectral_form` (their docstrings have the formulas) call them,
and ``tests/test_filters_discretisation.py`` checks both against scipy's expm and numpy's eig.

Compiled at first use and cached on disk (online_id/util/jit.py).
"""

from __future__ import annotations

import numpy as np

from online_id.util.jit import cached_njit


@cached_njit()
def descriptor_blocks(E0, A0, E_V, A_V, B_V, dE_flat, dA_flat, dAB_rows, dE_rows, AB_V, theta, speed):
    """[Ac, Bc] (n, n + 1) and [∂Ac/∂q, ∂Bc/∂q] (P + 1, n, n + 1) for q = θ_1..θ_P, V, from the affine
    coefficients of :func:`~online_id.model.discretise._affine_coefficients` (the same order).

    E [Ac, Bc] = [A, B] and E [∂Ac/∂q, ∂Bc/∂q] = [∂A/∂q, ∂B/∂q] − ∂E/∂q [Ac, Bc]; raises
    ``numpy.linalg.LinAlgError`` where E is singular (LAPACK's gesv, as numpy's solve).
    """
    n, P = dAB_rows.shape[0], dAB_rows.shape[1]
    E = E0 + speed * E_V + (theta @ dE_flat).reshape(n, n)
    AB = np.empty((n, n + 1))
    AB[:, :n] = A0 + speed * A_V + (theta @ dA_flat).reshape(n, n)
    AB[:, n] = speed * B_V
    AB = np.ascontiguousarray(np.linalg.solve(E, AB))  # (LAPACK's result is Fortran-ordered)
    rhs = np.empty((n, P + 1, n + 1))
    rhs[:, :P] = dAB_rows - (dE_rows @ AB).reshape(n, P, n + 1)
    rhs[:, P] = AB_V - E_V @ AB
    d = np.ascontiguousarray(np.linalg.solve(E, rhs.reshape(n, (P + 1) * (n + 1)))).reshape(n, P + 1, n + 1)
    out = np.empty((P + 1, n, n + 1))
    for k in range(P + 1):
        out[k] = d[:, k]
    return AB, out


@cached_njit()
def eigenbasis(wr, wi, vr, dG):  # pragma: no cover -- compiled
    """From LAPACK dgeev's eigenvalues (``wr`` + i ``wi``) and right eigenvectors ``vr`` of a real G (n, n),
    and K directions ``dG`` (K, n, n): λ (n,), Q and Q⁻¹ (n, n), W_k = Q⁻¹ dG_k Q (K, n, n), complex, and
    the condition ‖Q‖₁ ‖Q⁻¹‖₁.

    A complex pair's eigenvectors are VR[:, j] ± i VR[:, j + 1] (LAPACK's layout: the eigenvalue with the
    positive imaginary part first). Raises ``numpy.linalg.LinAlgError`` where Q is singular.
    """
    n, K = wr.shape[0], dG.shape[0]
    lam = np.empty(n, dtype=np.complex128)
    Q = np.empty((n, n), dtype=np.complex128)
    j = 0
    while j < n:
        lam[j] = complex(wr[j], wi[j])
        if wi[j] > 0 and j + 1 < n:
            lam[j + 1] = complex(wr[j + 1], wi[j + 1])
            for r in range(n):
                v = complex(vr[r, j], vr[r, j + 1])
                Q[r, j] = v
                Q[r, j + 1] = v.conjugate()
            j += 2
        else:
            if wi[j] != 0:  # (LAPACK lists a complex pair's two eigenvalues together, positive part first)
                raise np.linalg.LinAlgError("dgeev: a complex eigenvalue without its conjugate")
            for r in range(n):
                Q[r, j] = vr[r, j]
            j += 1
    Qi = np.linalg.inv(Q)
    norm_Q = 0.0
    norm_Qi = 0.0
    for c in range(n):
        sum_Q = 0.0
        sum_Qi = 0.0
        for r in range(n):
            sum_Q += abs(Q[r, c])
            sum_Qi += abs(Qi[r, c])
        norm_Q = max(norm_Q, sum_Q)
        norm_Qi = max(norm_Qi, sum_Qi)
    W = np.empty((K, n, n), dtype=np.complex128)
    T = np.empty((n, n), dtype=np.complex128)
    for k in range(K):
        for r in range(n):  # T = dG_k Q (dG_k real)
            for c in range(n):
                s = 0j
                for a in range(n):
                    s += dG[k, r, a] * Q[a, c]
                T[r, c] = s
        W[k] = Qi @ T
    return lam, Q, Qi, W, norm_Q * norm_Qi
