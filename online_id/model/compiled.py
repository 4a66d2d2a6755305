"""A linearisation point's arithmetic in compiled loops (numba), for :mod:`online_id.model.discretise`.

A point of the EKF (a new eigen-decomposition whenever the parameters or the speed move past their
steps) is a few hundred floating-point operations on 7 × 7 matrices spread over about 60 numpy calls:
on a weakly excited log, where the parameters move at every correction (the RAV4's), the calls' own
overhead was a fifth of the filter's time. These functions do the same arithmetic in one call each;
:func:`~online_id.model.discretise.derivative_blocks` and
:func:`~online_id.model.discretise.single_spectral_form` (their docstrings have the formulas) call them,
and ``tests/test_filters_discretisation.py`` checks both against scipy's expm and numpy's eig. For an input
polynomial between samples (model/intersample.py): the φ-functions of an eigenbasis and their divided
differences (:func:`phi_weights`, checked against sums in exact rationals) and the input columns they give
(:func:`input_table`, against expm of the augmented generator).

Compiled at first use and cached on disk (online_id/util/jit.py).
"""

from __future__ import annotations

import math

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


# -- φ-functions of an eigenbasis and their divided differences (the step of an input polynomial) --------------

#: Below this |μ| the φ-functions and their divided differences are summed as series; at and above it, the
#: recurrence through 1/μ (under one digit lost a step; the same split as model/intersample.py's phi_functions).
PHI_SERIES_RADIUS = 1.0
#: A series stops once its next term is below this (|μ| < 1: at most 20 terms; every value summed is ≥ 1/24).
PHI_SERIES_TAIL = 1e-18
#: 1/k!, k = 0..39 (the series' coefficients).
_INVERSE_FACTORIAL = np.array([1.0 / math.factorial(k) for k in range(40)])


@cached_njit()
def phi_weights(mu, close, series, phi, dd):  # pragma: no cover -- compiled
    """φ_j(μ_a) and the divided differences of φ_1 … φ_J over every pair of ``mu`` (n,) complex (μ = λ T of an
    eigenbasis), the weights of the input columns Γ_j = [φ_j(G T)]_{:, input} and of their Fréchet derivatives.

    ``phi`` (J + 1, n) ← φ_0 … φ_J at each μ_a (φ_0 = e^μ); ``dd`` (J, n, n) ← φ_j[μ_a, μ_b] for j = 1..J, the
    divided difference (φ_j(μ_a) − φ_j(μ_b))/(μ_a − μ_b), φ_j'(μ_a) where a = b; symmetric. Each entry on its
    own, so that a slow mode loses no digits beside a fast one:

    * |μ| ≥ 1: φ_j+1(μ) = (φ_j(μ) − 1/j!)/μ; for a pair whose larger |μ_p| ≥ 1 (μ_o the other), from
      φ_0[μ_p, μ_o] (e^(μ_p) on the diagonal; e^(μ_o) φ1(μ_p − μ_o) by its series where |μ_p − μ_o| < ``close``,
      ``series`` its coefficients 1/2, 1/6, 1/24, 1/120, as :meth:`SpectralForm.weights
      <online_id.model.discretise.SpectralForm.weights>`), the divided
      difference of z φ_j+1(z) = φ_j(z) − 1/j!:  φ_j+1[μ_p, μ_o] = (φ_j[μ_p, μ_o] − φ_j+1(μ_o))/μ_p;
    * |μ| < 1 (both of a pair): the series φ_J(μ) = Σ_k μ^k/(k + J)! and φ_J[μ_a, μ_b] = Σ_k≥1 h_k−1/(k + J)!,
      h_m = Σ_i μ_a^i μ_b^(m−i) (the divided difference of μ^(m+1)), until a bound on the terms is below
      PHI_SERIES_TAIL, then down to j = 1 by φ_j(μ) = μ φ_j+1(μ) + 1/j! and its divided difference
      φ_j[μ_p, μ_o] = μ_p φ_j+1[μ_p, μ_o] + φ_j+1(μ_o) (each term's error shrinks by |μ_p| < 1).
    """
    n = mu.shape[0]
    J = dd.shape[0]
    c = _INVERSE_FACTORIAL
    modulus = np.empty(n)
    for a in range(n):
        z = mu[a]
        phi[0, a] = np.exp(z)
        r = abs(z)
        modulus[a] = r
        if r >= PHI_SERIES_RADIUS:
            for j in range(J):
                phi[j + 1, a] = (phi[j, a] - c[j]) / z
        else:  # φ_J by its series, then down: φ_j = z φ_j+1 + 1/j! (stable for |z| < 1)
            acc = c[J] + 0j
            term = 1.0 + 0j
            bound = 1.0
            k = 1
            while k < 28:
                term = term * z
                acc += term * c[k + J]
                bound *= r
                if bound * c[k + J] < PHI_SERIES_TAIL:
                    break
                k += 1
            phi[J, a] = acc
            for j in range(J - 1, 0, -1):
                phi[j, a] = z * phi[j + 1, a] + c[j]
    for a in range(n):
        for b in range(a, n):
            if modulus[a] >= modulus[b]:
                p, o = a, b
            else:
                p, o = b, a
            zp, zo = mu[p], mu[o]
            if modulus[p] >= PHI_SERIES_RADIUS:
                if p == o:
                    d = phi[0, p]
                else:
                    gap = zp - zo
                    if gap.real * gap.real + gap.imag * gap.imag < close * close:
                        s = series
                        d = phi[0, o] * (1 + gap * (s[0] + gap * (s[1] + gap * (s[2] + gap * s[3]))))
                    else:
                        d = (phi[0, p] - phi[0, o]) / gap
                for j in range(J):
                    d = (d - phi[j + 1, o]) / zp
                    dd[j, a, b] = d
                    dd[j, b, a] = d
            else:  # φ_J[μ_p, μ_o] = Σ_m≥0 h_m/(m + J + 1)! by its series, then down (stable: |μ_p| < 1)
                h = 1.0 + 0j  # h_0
                power = 1.0 + 0j  # μ_o^m
                rp, bound = modulus[p], 1.0  # |h_m| ≤ (m + 1) |μ_p|^m (h_m itself may cancel to 0: no stop on it)
                d = c[J + 1] + 0j
                m = 1
                while m < 28:
                    power = power * zo
                    h = zp * h + power  # h_m = μ_p h_m−1 + μ_o^m
                    d += h * c[m + J + 1]
                    bound *= rp
                    if (m + 1) * bound * c[m + J + 1] < PHI_SERIES_TAIL:
                        break
                    m += 1
                dd[J - 1, a, b] = d
                dd[J - 1, b, a] = d
                for j in range(J - 1, 0, -1):  # φ_j[μ_p, μ_o] = μ_p φ_j+1[μ_p, μ_o] + φ_j+1(μ_o)
                    d = zp * d + phi[j + 1, o]
                    dd[j - 1, a, b] = d
                    dd[j - 1, b, a] = d


@cached_njit()
def input_table(lam, Q, Qi, W, dt, close, series, Gamma, LG):  # pragma: no cover -- compiled
    """The input columns of an input polynomial for one period ``dt`` [s] from an eigen-decomposition
    G = Q diag(λ) Q⁻¹ (n, n) whose last state is the input, and their first-order terms in K directions with
    W_k = Q⁻¹ dG_k Q (K, n, n): with q = Q⁻¹[:, n − 1] and μ = λ dt (:func:`phi_weights`),

        Gamma[:, j−1] = Re(Q (φ_j(μ) ∘ q))[:n − 1],   LG[k, :, j−1] = Re(Q ((dt φ_j[μ_a, μ_b] ∘ W_k) q))[:n − 1],

    for j = 1..J: ``Gamma`` (n − 1, J) and ``LG`` (K, n − 1, J), filled in place."""
    n = lam.shape[0]
    ns = n - 1
    J = Gamma.shape[1]
    K = W.shape[0]
    mu = np.empty(n, dtype=np.complex128)
    for a in range(n):
        mu[a] = lam[a] * dt
    phi = np.empty((J + 1, n), dtype=np.complex128)
    dd = np.empty((J, n, n), dtype=np.complex128)
    phi_weights(mu, close, series, phi, dd)
    q = np.empty(n, dtype=np.complex128)
    for a in range(n):
        q[a] = Qi[a, ns]
    v = np.empty(n, dtype=np.complex128)
    for j in range(J):
        for r in range(ns):
            acc = 0.0
            for a in range(n):
                z = Q[r, a] * (phi[j + 1, a] * q[a])
                acc += z.real
            Gamma[r, j] = acc
    for k in range(K):
        for j in range(J):
            for a in range(n):
                acc = 0j
                for b in range(n):
                    acc += W[k, a, b] * dd[j, a, b] * q[b]
                v[a] = acc * dt
            for r in range(ns):
                acc2 = 0.0
                for a in range(n):
                    z = Q[r, a] * v[a]
                    acc2 += z.real
                LG[k, r, j] = acc2


@cached_njit()
def period_table(lam, Q, Qi, W, dt, close, series, Phi, L):  # pragma: no cover -- compiled
    """Φ(dt) = Re(Q diag(e^(λ dt)) Q⁻¹) (n, n) and each direction's L_k(dt) = Re(Q (D ∘ W_k) Q⁻¹) (K, n, n) of
    one eigen-decomposition for one period ``dt`` [s], filled in place: D_ab = (e^(μa) − e^(μb)) / (λa − λb)
    with μ = λ dt, or dt e^(μb) φ1(μa − μb) by the series ``series`` where |μa − μb| < ``close`` (the diagonal
    among them) (:meth:`SpectralForm.period_table <online_id.model.discretise.SpectralForm.period_table>`,
    whose numpy products this is in one call: issue 36's 100 Hz cost, a new point every few corrections)."""
    n = lam.shape[0]
    K = W.shape[0]
    e = np.empty(n, dtype=np.complex128)
    mu = np.empty(n, dtype=np.complex128)
    for a in range(n):
        mu[a] = lam[a] * dt
        e[a] = np.exp(mu[a])
    D = np.empty((n, n), dtype=np.complex128)
    for a in range(n):
        for b in range(n):
            z = mu[a] - mu[b]
            if abs(z) < close:
                D[a, b] = dt * e[b] * (1 + z * (series[0] + z * (series[1] + z * (series[2] + z * series[3]))))
            else:
                D[a, b] = (e[a] - e[b]) / (lam[a] - lam[b])
    for r in range(n):
        for c in range(n):
            acc = 0.0
            for a in range(n):
                acc += (Q[r, a] * e[a] * Qi[a, c]).real
            Phi[r, c] = acc
    T = np.empty((n, n), dtype=np.complex128)
    for k in range(K):
        for r in range(n):
            for b in range(n):
                acc = 0j
                for a in range(n):
                    acc += Q[r, a] * (D[a, b] * W[k, a, b])
                T[r, b] = acc
        for r in range(n):
            for c in range(n):
                acc = 0.0
                for b in range(n):
                    acc += (T[r, b] * Qi[b, c]).real
                L[k, r, c] = acc


@cached_njit()
def local_tables(lam, Q, Qi, W, dt, close, series, n_params, J):  # pragma: no cover -- compiled
    """A linearisation point's tables for one period ``dt`` [s] in one call (filters/local_model.py
    ``LocalModel._tables``, issue 36's 100 Hz cost: a new point every few corrections): :func:`period_table`'s
    Φ (n², flat) and L_k (K, n², flat); the parameters' columns table (n + J, P·(n − 1)): row r < n, column
    p·(n − 1) + a is L_p[a, r], row n + j is ∂Γ_j+1/∂s_p [a] (parameter-major); with an input polynomial (J > 0)
    :func:`input_table`'s Γ_1..Γ_J ((n − 1)·J, flat) and their first-order terms (K, (n − 1)·J), else empty. The
    same numbers as the two tables and the numpy reshapes the point made of them."""
    n = lam.shape[0]
    ns = n - 1
    K = W.shape[0]
    Phi = np.empty((n, n))
    L = np.empty((K, n, n))
    period_table(lam, Q, Qi, W, dt, close, series, Phi, L)
    columns = np.empty((n + J, n_params * ns))
    for p in range(n_params):
        for a in range(ns):
            for r in range(n):
                columns[r, p * ns + a] = L[p, a, r]
    Gamma = np.empty((ns, J))
    LG = np.empty((K, ns, J))
    if J > 0:
        input_table(lam, Q, Qi, W, dt, close, series, Gamma, LG)
        for j in range(J):
            for p in range(n_params):
                for a in range(ns):
                    columns[n + j, p * ns + a] = LG[p, a, j]
    return Phi.reshape(n * n), L.reshape(K, n * n), columns, Gamma.reshape(ns * J), LG.reshape(K, ns * J)


# -- expm and its Fréchet derivatives of a small matrix, by scaling and squaring a Padé approximant --------

#: Al-Mohy & Higham (2009), "A new scaling and squaring algorithm for the matrix exponential", table 2.3:
#: the largest 1-norm of X for which the [m/m] Padé approximant's backward error is under 2⁻⁵³, m = 3, 5, 7,
#: 9, 13 (scipy's expm uses the same; it refines the choice with norms of powers, which can only pick a
#: lower degree than the plain 1-norm does here).
PADE_THETA = np.array([1.495585217958292e-2, 2.539398330063230e-1, 9.504178996162932e-1, 2.097847961257068,
                       5.371920351148152])
_PADE_B = np.zeros((5, 14))
_PADE_B[0, :4] = (120.0, 60.0, 12.0, 1.0)
_PADE_B[1, :6] = (30240.0, 15120.0, 3360.0, 420.0, 30.0, 1.0)
_PADE_B[2, :8] = (17297280.0, 8648640.0, 1995840.0, 277200.0, 25200.0, 1512.0, 56.0, 1.0)
_PADE_B[3, :10] = (17643225600.0, 8821612800.0, 2075673600.0, 302702400.0, 30270240.0, 2162160.0, 110880.0,
                   3960.0, 90.0, 1.0)
_PADE_B[4, :] = (64764752532480000.0, 32382376266240000.0, 7771770303897600.0, 1187353796428800.0,
                 129060195264000.0, 10559470521600.0, 670442572800.0, 33522128640.0, 1323241920.0, 40840800.0,
                 960960.0, 16380.0, 182.0, 1.0)


#: The generator of the lateral model with a cubic input's chain (filters/sigma_block.py ``sigma_expm_steps``):
#: 7 + 3 rows, its lower-left 3 × 7 block zero (the chain's rows reach only the chain).
_CHAIN_SIZE, _CHAIN_SPLIT = 10, 7


@cached_njit()
def _matmul_chain_into(A, B, out):  # pragma: no cover -- compiled
    """out = A @ B (10 × 10) in loops of fixed length; where A's and B's lower-left 3 × 7 blocks are zero (every
    product of :func:`expm_frechet` at the chain's generator, block upper triangular), out's is zero and the
    other blocks' sums leave out the products with that block: the same sums (the terms left out are exact
    zeros), at half the cost."""
    m, k0 = _CHAIN_SIZE, _CHAIN_SPLIT
    blocked = True
    for i in range(k0, m):
        for j in range(k0):
            if A[i, j] != 0.0 or B[i, j] != 0.0:
                blocked = False
    if not blocked:
        for i in range(m):
            for j in range(m):
                acc = 0.0
                for k in range(m):
                    acc += A[i, k] * B[k, j]
                out[i, j] = acc
        return
    for i in range(k0):
        for j in range(k0):
            acc = 0.0
            for k in range(k0):
                acc += A[i, k] * B[k, j]
            out[i, j] = acc
        for j in range(k0, m):
            acc = 0.0
            for k in range(m):
                acc += A[i, k] * B[k, j]
            out[i, j] = acc
    for i in range(k0, m):
        for j in range(k0):
            out[i, j] = 0.0
        for j in range(k0, m):
            acc = 0.0
            for k in range(k0, m):
                acc += A[i, k] * B[k, j]
            out[i, j] = acc


@cached_njit()
def _matmul_into(A, B, out):  # pragma: no cover -- compiled
    """out = A @ B for small square matrices (plain loops: no call into BLAS for a 7 × 7; the lateral model's
    7 × 7 in loops of fixed length, which the compiler unrolls: twice as fast; its 10 × 10 with a cubic input's
    chain by :func:`_matmul_chain_into`). Each entry sums its products in order from 0.0."""
    n = A.shape[0]
    if n == _CHAIN_SIZE:
        _matmul_chain_into(A, B, out)
        return
    if n == 7:
        for i in range(7):
            for j in range(7):
                acc = 0.0
                for k in range(7):
                    acc += A[i, k] * B[k, j]
                out[i, j] = acc
        return
    for i in range(n):
        for j in range(n):
            acc = 0.0
            for k in range(n):
                acc += A[i, k] * B[k, j]
            out[i, j] = acc


@cached_njit()
def _lu_factor(A, piv):  # pragma: no cover -- compiled
    """A (n, n) ← its LU factors with partial pivoting (LAPACK getrf's), the row swaps in ``piv``; raises
    ``numpy.linalg.LinAlgError`` where A is singular."""
    n = A.shape[0]
    for j in range(n):
        p = j
        big = abs(A[j, j])
        for i in range(j + 1, n):
            if abs(A[i, j]) > big:
                big = abs(A[i, j])
                p = i
        piv[j] = p
        if big == 0.0:
            raise np.linalg.LinAlgError("singular matrix")
        if p != j:
            for c in range(n):
                t = A[j, c]
                A[j, c] = A[p, c]
                A[p, c] = t
        inv = 1.0 / A[j, j]
        for i in range(j + 1, n):
            f = A[i, j] * inv
            A[i, j] = f
            if f != 0.0:
                for c in range(j + 1, n):
                    A[i, c] -= f * A[j, c]


@cached_njit()
def _lu_solve(LU, piv, B):  # pragma: no cover -- compiled
    """B (n, r) ← A⁻¹ B from :func:`_lu_factor`'s factors of A."""
    n, r = B.shape
    for j in range(n):
        p = piv[j]
        if p != j:
            for c in range(r):
                t = B[j, c]
                B[j, c] = B[p, c]
                B[p, c] = t
    for i in range(n):
        for k in range(i):
            f = LU[i, k]
            if f != 0.0:
                for c in range(r):
                    B[i, c] -= f * B[k, c]
    for i in range(n - 1, -1, -1):
        for k in range(i + 1, n):
            f = LU[i, k]
            if f != 0.0:
                for c in range(r):
                    B[i, c] -= f * B[k, c]
        inv = 1.0 / LU[i, i]
        for c in range(r):
            B[i, c] *= inv


@cached_njit()
def _combine(out, c0, M0, c1, M1, c2, M2, c3, M3):  # pragma: no cover -- compiled
    """out = c0 M0 + c1 M1 + c2 M2 + c3 M3 (n, n)."""
    n = out.shape[0]
    for i in range(n):
        for j in range(n):
            out[i, j] = c0 * M0[i, j] + c1 * M1[i, j] + c2 * M2[i, j] + c3 * M3[i, j]


@cached_njit()
def _product_derivative(A, LA, B, LB, out, T):  # pragma: no cover -- compiled
    """out = A LB + LA B: the derivative of the product AB (T: a scratch (n, n))."""
    _matmul_into(A, LB, out)
    _matmul_into(LA, B, T)
    n = out.shape[0]
    for i in range(n):
        for j in range(n):
            out[i, j] += T[i, j]


@cached_njit()
def expm_frechet(X, E, F, L):  # pragma: no cover -- compiled
    """F = expm(X) (n, n) and L[k] = the Fréchet derivative of expm at X in direction E[k] (K, n, n; K may be
    0), by scaling and squaring the [m/m] Padé approximant (Al-Mohy & Higham 2009: expm; and 2009b,
    "Computing the Fréchet derivative of the matrix exponential", algorithm 6.4: scipy's expm_frechet).

    The degree m is the lowest of 3, 5, 7, 9 whose :data:`PADE_THETA` bounds ‖X‖₁, else 13 after scaling X by
    2⁻ˢ: backward error under 2⁻⁵³, so F agrees with scipy's expm to round-off. Each derivative is the same
    polynomials' derivatives (products (A, L_A)(B, L_B) = (AB, A L_B + L_A B)), the solve's, and the
    squarings' (L ← F L + L F). One scratch array for all the intermediate matrices.
    """
    n = X.shape[0]
    K = E.shape[0]
    norm = 0.0
    for j in range(n):
        col = 0.0
        for i in range(n):
            col += abs(X[i, j])
        norm = max(norm, col)
    s = 0
    deg = 4
    for d in range(4):
        if norm <= PADE_THETA[d]:
            deg = d
            break
    if deg == 4 and norm > PADE_THETA[4]:
        s = max(0, int(np.ceil(np.log2(norm / PADE_THETA[4]))))
    scale = 2.0 ** -s
    b = _PADE_B[deg]
    # scratch: A, P[0..4] (A^(2j)), T1, T2, Uo, V, U, Q, W1, W2, Z1, Z2, then per direction k: E_k scaled,
    # M[k, 1..4] (the derivatives of P), L_Uo, L_V, and for m = 13 four more
    base = 18
    per = 11
    work = np.empty((base + per * K, n, n))
    A, P, T1, T2 = work[0], work[1:6], work[6], work[7]
    Uo, V, U, Q = work[8], work[9], work[10], work[11]
    W1, W2, Z1, Z2 = work[12], work[13], work[14], work[15]
    for i in range(n):
        for j in range(n):
            A[i, j] = X[i, j] * scale
            P[0, i, j] = 1.0 if i == j else 0.0
    for k in range(K):
        Ek = work[base + per * k]
        for i in range(n):
            for j in range(n):
                Ek[i, j] = E[k, i, j] * scale
    # even powers P[j] = A^(2j), j ≤ 3 (4 for m = 9), and their derivatives M[k, j]
    top = 4 if deg == 3 else (3 if deg >= 2 else 2)
    _matmul_into(A, A, P[1])
    for k in range(K):
        o = base + per * k
        _product_derivative(A, work[o], A, work[o], work[o + 1], T1)
    for j in range(2, top + 1):
        h = 2 if j == 4 else 1  # A⁴ = A² A², A⁶ = A² A⁴, A⁸ = A⁴ A⁴
        _matmul_into(P[h], P[j - h], P[j])
        for k in range(K):
            o = base + per * k
            _product_derivative(P[h], work[o + h], P[j - h], work[o + j - h], work[o + j], T1)
    # U = A·Uo, V: Uo = Σ b_j A^(j−1) over odd j, V = Σ b_j A^j over even j (m = 13: in Horner form on A⁶)
    zero = T2
    zero[:] = 0.0
    if deg < 4:
        Uo[:] = 0.0
        V[:] = 0.0
        for j in range(deg + 2):
            bo, be = b[2 * j + 1], b[2 * j]
            for r in range(n):
                for c in range(n):
                    Uo[r, c] += bo * P[j, r, c]
                    V[r, c] += be * P[j, r, c]
        for k in range(K):
            o = base + per * k
            LUo, LV = work[o + 5], work[o + 6]
            LUo[:] = 0.0
            LV[:] = 0.0
            for j in range(1, deg + 2):
                bo, be = b[2 * j + 1], b[2 * j]
                Mj = work[o + j]
                for r in range(n):
                    for c in range(n):
                        LUo[r, c] += bo * Mj[r, c]
                        LV[r, c] += be * Mj[r, c]
    else:
        _combine(W1, b[13], P[3], b[11], P[2], b[9], P[1], 0.0, zero)
        _combine(W2, b[7], P[3], b[5], P[2], b[3], P[1], b[1], P[0])
        _combine(Z1, b[12], P[3], b[10], P[2], b[8], P[1], 0.0, zero)
        _combine(Z2, b[6], P[3], b[4], P[2], b[2], P[1], b[0], P[0])
        _matmul_into(P[3], W1, Uo)
        _matmul_into(P[3], Z1, V)
        for r in range(n):
            for c in range(n):
                Uo[r, c] += W2[r, c]
                V[r, c] += Z2[r, c]
        for k in range(K):
            o = base + per * k
            M1, M2, M3 = work[o + 1], work[o + 2], work[o + 3]
            LUo, LV, LW1, LW2, LZ1, LZ2 = work[o + 5], work[o + 6], work[o + 7], work[o + 8], work[o + 9], work[o + 10]
            _combine(LW1, b[13], M3, b[11], M2, b[9], M1, 0.0, zero)
            _combine(LW2, b[7], M3, b[5], M2, b[3], M1, 0.0, zero)
            _combine(LZ1, b[12], M3, b[10], M2, b[8], M1, 0.0, zero)
            _combine(LZ2, b[6], M3, b[4], M2, b[2], M1, 0.0, zero)
            _product_derivative(P[3], M3, W1, LW1, LUo, T1)
            _product_derivative(P[3], M3, Z1, LZ1, LV, T1)
            for r in range(n):
                for c in range(n):
                    LUo[r, c] += LW2[r, c]
                    LV[r, c] += LZ2[r, c]
    _matmul_into(A, Uo, U)
    # R = (V − U)⁻¹ (V + U); L_R = (V − U)⁻¹ (L_U + L_V + (L_U − L_V) R), L_U = E Uo + A L_Uo
    for r in range(n):
        for c in range(n):
            Q[r, c] = V[r, c] - U[r, c]
            F[r, c] = V[r, c] + U[r, c]
    piv = np.empty(n, dtype=np.int64)
    _lu_factor(Q, piv)
    _lu_solve(Q, piv, F)
    for k in range(K):
        o = base + per * k
        LUo, LV, LU = work[o + 5], work[o + 6], work[o + 7]
        _product_derivative(A, work[o], Uo, LUo, LU, T1)  # L_U = A L_Uo + E Uo
        for r in range(n):
            for c in range(n):
                T2[r, c] = LU[r, c] - LV[r, c]
        _matmul_into(T2, F, T1)
        Lk = L[k]
        for r in range(n):
            for c in range(n):
                Lk[r, c] = LU[r, c] + LV[r, c] + T1[r, c]
        _lu_solve(Q, piv, Lk)
    for _ in range(s):
        for k in range(K):
            _product_derivative(F, L[k], F, L[k], T2, T1)
            L[k, :, :] = T2
        _matmul_into(F, F, T1)
        F[:, :] = T1


@cached_njit()
def speed_generators(E0, A0, E_V, A_V, B_V, dE_flat, dA_flat, thetas, speed, G, dG):  # pragma: no cover
    """For each parameter set ``thetas`` (S, P) at one ``speed``: G = [[Ac, Bc], [0, 0]] (S, n + 1, n + 1) and
    its derivative in V, dG (S, n + 1, n + 1), filled in place (their last rows zero), from the affine
    coefficients of :func:`~online_id.model.discretise._affine_coefficients`.

    E [Ac, Bc] = [A, B] and E [∂Ac/∂V, ∂Bc/∂V] = [∂A/∂V, ∂B/∂V] − ∂E/∂V [Ac, Bc], by one LU factorisation of E
    (partial pivoting) per set; raises ``numpy.linalg.LinAlgError`` where E is singular.
    """
    S, P = thetas.shape
    n = E0.shape[0]
    E = np.empty((n, n))
    rhs = np.empty((n, n + 1))
    piv = np.empty(n, dtype=np.int64)
    for s in range(S):
        for r in range(n):
            for c in range(n):
                E[r, c] = E0[r, c] + speed * E_V[r, c]
                rhs[r, c] = A0[r, c] + speed * A_V[r, c]
            rhs[r, n] = speed * B_V[r]
        for i in range(P):  # (the θ-terms row by row of the flattened coefficients: contiguous reads)
            t = thetas[s, i]
            for r in range(n):
                for c in range(n):
                    E[r, c] += t * dE_flat[i, r * n + c]
                    rhs[r, c] += t * dA_flat[i, r * n + c]
        _lu_factor(E, piv)
        _lu_solve(E, piv, rhs)
        for r in range(n):
            for c in range(n + 1):
                G[s, r, c] = rhs[r, c]
        for c in range(n + 1):  # ∂/∂V: [A_V, B_V] − E_V [Ac, Bc], then E⁻¹ of it
            for r in range(n):
                acc = B_V[r] if c == n else A_V[r, c]
                for k in range(n):
                    acc -= E_V[r, k] * G[s, k, c]
                rhs[r, c] = acc
        _lu_solve(E, piv, rhs)
        for r in range(n):
            for c in range(n + 1):
                dG[s, r, c] = rhs[r, c]
        for c in range(n + 1):
            G[s, n, c] = 0.0
            dG[s, n, c] = 0.0
