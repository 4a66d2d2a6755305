"""A group of samples whose period (and speed) varies at every sample, in compiled code.

A CAN log's sample period jitters (the RAV4 log's runs 0.1-29 ms), so no two steps of a group share
a transition and the one-period tables of :meth:`LocalModel.steps <online_id.filters.local_model.LocalModel.steps>`
do not apply. Worked with numpy, such a group costs about 30 array operations of a few microseconds each
on 7 × 7 matrices (the spectral steps, the transition table, the parameter columns, the chained
Jacobians: ~250 µs for 20 samples, twice a one-period group). Here the same arithmetic runs sample by
sample in one compiled loop (numba), from one linearisation point's eigen-decomposition
(:class:`~online_id.model.discretise.SpectralForm`): for each sample j, with μ = λ dt_j,

    e_a = e^(μ_a),   D_ab = (e_a − e_b) / (λ_a − λ_b)   (dt_j e^(μ_b) φ1(μ_a − μ_b) where |μ_a − μ_b| < 1e-3),
    [Ad_j, Bd_j] = rows 1-6 of Re(Q (diag(e) + D ∘ Σ_k c_jk W_k) Q⁻¹),        (first order in c_j = [Δs, ΔV_j])
    x_j = Ad_j x_j-1 + Γ_j w_j,     (Γ_j,0 = Bd_j; the hold: w_j = δ_j alone)
    J_j[:, i] = rows 1-6 of Re(Q (D ∘ W_i) Q⁻¹ [x_j-1; w_j,0])   (parameter i's column, at the point itself),
    F_j = Ad_j F_j-1 + [0 | J_j | Bd_j gᵀ],

and with an input polynomial (w_j (4,), model/intersample.py), with q = Q⁻¹[:, 6], φ_k of each μ_a and their
divided differences φ_k[μ_a, μ_b] (:func:`online_id.model.compiled.phi_weights`), M_j = Σ_k c_jk W_k:

    Γ_j,k = rows 1-6 of Re(Q (φ_k(μ) ∘ q + (dt_j φ_k[μ_a, μ_b] ∘ M_j) q)),   k = 1..3 (first order in c_j),
    J_j[:, i] += Σ_k≥1 rows 1-6 of Re(Q (dt_j φ_k[μ_a, μ_b] ∘ W_i) q) w_j,k.

These are the formulas of :meth:`SpectralForm.weights`, :meth:`~SpectralForm.transitions_weighted`,
:meth:`~SpectralForm.directional_weighted` and :meth:`~SpectralForm.input_table` and the recursion that
:func:`~online_id.filters.groups.transition_table` and :func:`~online_id.filters.groups.chain_jacobians` unroll;
``tests/test_spectral_group.py`` checks the two agree to round-off (1e-11 of the largest entry) on random
points, jittered periods and close eigenvalues, with the hold's and with a cubic's inputs. The hold (K = 1)
runs the arithmetic it ran before issue 36, its numbers bit for bit (compared compiled afresh: with fastmath a
cached compile of this loop and a fresh one may differ in the last bits, on main as here); a cubic adds one
call of :func:`~online_id.model.compiled.phi_weights` per sample and its terms to the same passes.

The loop is compiled once (a few seconds) and cached on disk beside this file (numba's cache; where that
is not writable, in numba's user cache directory or ``NUMBA_CACHE_DIR``; where nothing is, compiled in
each process: online_id/util/jit.py); the EKF loads it when it is made
(:func:`~online_id.filters.local_model.compile_now`), not at its first jittering group.
"""

from __future__ import annotations

import numpy as np

from online_id.model.compiled import phi_weights
from online_id.model.discretise import DIVIDED_DIFFERENCE_CLOSE, PHI1_SERIES
from online_id.model.intersample import ORDER
from online_id.model.lateral import N_STATES
from online_id.util.jit import cached_njit


@cached_njit(fastmath=True)
def _product_rows(Ar, Am, Br, Bm, out_r, out_m):  # pragma: no cover -- compiled
    """out = (A B)[:rows] for complex A = Ar + i Am, B = Br + i Bm given by parts, rows = len(out_r); the
    inner loop runs along B's rows (contiguous: vectorised)."""
    out_r[:] = 0.0
    out_m[:] = 0.0
    for r in range(out_r.shape[0]):
        for a in range(Br.shape[0]):
            xr, xm = Ar[r, a], Am[r, a]
            for c in range(out_r.shape[1]):
                out_r[r, c] += xr * Br[a, c] - xm * Bm[a, c]
                out_m[r, c] += xr * Bm[a, c] + xm * Br[a, c]


@cached_njit(fastmath=True)
def _real_product_rows(Ar, Am, Br, Bm, out):  # pragma: no cover -- compiled
    """out = Re(A B)[:rows], as :func:`_product_rows` (real parts only)."""
    out[:] = 0.0
    for r in range(out.shape[0]):
        for a in range(Br.shape[0]):
            xr, xm = Ar[r, a], Am[r, a]
            for c in range(out.shape[1]):
                out[r, c] += xr * Br[a, c] - xm * Bm[a, c]


@cached_njit(fastmath=True)
def _group(lam, Q, Qi, W, dt, ds, dV, w, steering, close, series, X, F):  # pragma: no cover -- compiled
    """The loop of :func:`propagate_group` (its docstring has the shapes); fills X[1:] and F[1:].

    Complex matrices are split into real and imaginary parts, and every inner loop runs along a
    contiguous last axis, so that the compiler vectorises it.
    """
    n = lam.shape[0]
    ns = n - 1  # the model states: the last row of G (the held input) is zero
    n_params = W.shape[0] - 1  # the directions: the parameters', then the speed's
    N = F.shape[2]
    n_extra = steering.shape[0]
    K = w.shape[1]  # the steps' input: w_0 (the held value, Γ_0 = Bd), then w_1 … (an input polynomial)
    Qr, Qm, Pr, Pm = Q.real.copy(), Q.imag.copy(), Qi.real.copy(), Qi.imag.copy()  # Q, Q⁻¹
    Wr = np.empty((n, n, n_params))  # the parameters' W_i as [a, b, i]
    Wm = np.empty((n, n, n_params))
    for i in range(n_params):
        for a in range(n):
            for b in range(n):
                Wr[a, b, i] = W[i, a, b].real
                Wm[a, b, i] = W[i, a, b].imag
    shift = np.zeros((n, n), dtype=np.complex128)  # Σ_i Δs_i W_i: the same for every sample
    for i in range(n_params):
        for a in range(n):
            for b in range(n):
                shift[a, b] += ds[i] * W[i, a, b]
    inverse_gap = np.zeros((n, n), dtype=np.complex128)  # 1/(λa − λb) where they differ; |λa − λb|
    distance = np.zeros((n, n))
    for a in range(n):
        for b in range(n):
            distance[a, b] = abs(lam[a] - lam[b])
            if a != b and distance[a, b] > 0:
                inverse_gap[a, b] = 1 / (lam[a] - lam[b])
    e = np.empty(n, dtype=np.complex128)
    D = np.empty((n, n), dtype=np.complex128)
    Mr = np.empty((n, n))
    Mm = np.empty((n, n))
    QMr = np.empty((ns, n))
    QMm = np.empty((ns, n))
    y = np.empty(n, dtype=np.complex128)
    Ur = np.empty((n, n_params))
    Um = np.empty((n, n_params))
    Phi = np.empty((ns, n))
    cols = np.empty((ns, n_params))
    # an input polynomial's columns (K > 1): φ_j(μ), their divided differences, q = Q⁻¹[:, input]
    mu = np.empty(n, dtype=np.complex128)
    phi = np.empty((K, n), dtype=np.complex128)
    dd = np.empty((K - 1, n, n), dtype=np.complex128)
    g = np.empty(n, dtype=np.complex128)
    q = np.empty(n, dtype=np.complex128)
    for a in range(n):
        q[a] = Qi[a, ns]
    for j in range(dt.shape[0]):
        h = dt[j]
        for a in range(n):
            e[a] = np.exp(lam[a] * h)
        for a in range(n):
            for b in range(n):
                if a == b:
                    D[a, b] = h * e[a]
                elif distance[a, b] * h < close:
                    z = (lam[a] - lam[b]) * h
                    c = PHI1_SERIES  # (a module-level tuple: numba freezes it into the loop)
                    D[a, b] = h * e[b] * (1 + z * (c[0] + z * (c[1] + z * (c[2] + z * c[3]))))
                else:
                    D[a, b] = (e[a] - e[b]) * inverse_gap[a, b]
        # the step: Q (diag(e) + D ∘ (Σ_i Δs_i W_i + ΔV_j W_V)) Q⁻¹, its first six rows
        for a in range(n):
            for b in range(n):
                v = D[a, b] * (shift[a, b] + dV[j] * W[n_params, a, b])
                if a == b:
                    v += e[a]
                Mr[a, b] = v.real
                Mm[a, b] = v.imag
        _product_rows(Qr, Qm, Mr, Mm, QMr, QMm)
        _real_product_rows(QMr, QMm, Pr, Pm, Phi)
        # the parameters' columns at the point, from the state before the step: y = Q⁻¹ [x_j-1; δ_j],
        # U[a, i] = Σ_b W_i[a, b] D_ab y_b, J = Re(Q U)
        for a in range(n):
            v = Qi[a, ns] * w[j, 0]
            for b in range(ns):
                v += Qi[a, b] * X[j, b]
            y[a] = v
        Ur[:] = 0.0
        Um[:] = 0.0
        if K > 1:
            # an input polynomial: Γ_k = Re(Q (φ_k(μ) ∘ q + (dt φ_k[μ_a, μ_b] ∘ M) q))[:6] with M = Σ_i Δs_i W_i
            # + ΔV_j W_V (first order), and the parameters' columns gain Σ_k Re(Q (dt φ_k[μ_a, μ_b] ∘ W_i) q) w_k:
            # with E_ab = dt Σ_k w_k φ_k[μ_a, μ_b] q_b, U[a, i] = Σ_b W_i[a, b] (D_ab y_b + E_ab) and
            # g_a = Σ_k w_k φ_k(μ_a) q_a + Σ_b E_ab M_ab, Γ w = Re(Q g)[:6] (k ≥ 1; w_0's column is Φ's)
            for a in range(n):
                mu[a] = lam[a] * h
            phi_weights(mu, close, series, phi, dd)
            for a in range(n):
                v = 0j
                for k in range(1, K):
                    v += w[j, k] * phi[k, a]
                ga = v * q[a]
                for b in range(n):
                    u = 0j
                    for k in range(1, K):
                        u += w[j, k] * dd[k - 1, a, b]
                    u = u * h * q[b]
                    ga += u * (shift[a, b] + dV[j] * W[n_params, a, b])
                    v = D[a, b] * y[b] + u
                    vr, vm = v.real, v.imag
                    for i in range(n_params):
                        Ur[a, i] += Wr[a, b, i] * vr - Wm[a, b, i] * vm
                        Um[a, i] += Wr[a, b, i] * vm + Wm[a, b, i] * vr
                g[a] = ga
        else:
            for a in range(n):
                for b in range(n):
                    v = D[a, b] * y[b]
                    vr, vm = v.real, v.imag
                    for i in range(n_params):
                        Ur[a, i] += Wr[a, b, i] * vr - Wm[a, b, i] * vm
                        Um[a, i] += Wr[a, b, i] * vm + Wm[a, b, i] * vr
        _real_product_rows(Qr, Qm, Ur, Um, cols)
        # the mean and the chained Jacobian
        for r in range(ns):
            v = Phi[r, ns] * w[j, 0]
            for c in range(ns):
                v += Phi[r, c] * X[j, c]
            X[j + 1, r] = v
        if K > 1:
            for r in range(ns):
                v = 0.0
                for a in range(n):
                    v += Qr[r, a] * g[a].real - Qm[r, a] * g[a].imag
                X[j + 1, r] += v
        F[j + 1] = 0.0
        for r in range(ns):
            for b in range(ns):
                p = Phi[r, b]
                for c in range(N):
                    F[j + 1, r, c] += p * F[j, b, c]
            for i in range(n_params):
                F[j + 1, r, ns + i] += cols[r, i]
            for k in range(n_extra):
                F[j + 1, r, ns + n_params + k] += Phi[r, ns] * steering[k]


def propagate_group(form, dt, ds, dV, w, X, F, steering=None) -> None:
    """The mean and chained Jacobians of a group of m samples at one linearisation point, in place.

    ``form``: the point's :class:`~online_id.model.discretise.SpectralForm` (one decomposition; its
    directions: P parameters' (log scale), then the speed's); ``dt`` (m,) periods [s]; ``ds`` (P,) the
    parameters' distance from the point (the same for the whole group) and ``dV`` (m,) each step's speed's
    [m/s]; ``w`` (m, K) each step's input (model/intersample.py: the road-wheel angle's value and derivatives in
    normalised time [rad]; K = 1 or a vector (m,): the angle held over each step).

    ``X`` (m + 1, 6) and ``F`` (m + 1, 6, N) (C-contiguous float arrays) hold the model states and the
    chained Jacobian before the group in their first rows; the rest is filled as
    :func:`~online_id.filters.groups.propagate_mean` and :func:`~online_id.filters.groups.chain_jacobians`
    do. N = 6 + P + n with n extra states whose columns are Bd_j gᵀ (``steering`` g (n,),
    filters/augment.py; none by default).
    """
    m, n_params = len(dt), len(form.directions) - 1
    n_extra = 0 if steering is None else len(steering)
    w = np.asarray(w, dtype=float)
    if w.ndim == 1:
        w = w[:, None]
    if X.shape != (m + 1, N_STATES) or F.shape != (m + 1, N_STATES, N_STATES + n_params + n_extra):
        raise ValueError(f"propagate_group: X {X.shape} and F {F.shape} do not fit {m} samples, "
                         f"{n_params} parameters and {n_extra} extra states")
    if len(ds) != n_params or len(dV) != m or len(w) != m or not 1 <= w.shape[1] <= ORDER:
        raise ValueError(f"propagate_group: ds {len(ds)}, dV {len(dV)}, w {w.shape} do not fit "
                         f"{n_params} parameters and {m} samples")
    c = np.ascontiguousarray  # one layout, one compiled version (LAPACK hands back Fortran-ordered arrays)
    _group(c(form.eigenvalues), c(form.vectors), c(form.inverse), c(form.directions), c(dt, dtype=float),
           c(ds, dtype=float), c(dV, dtype=float), c(w), _NO_EXTRA if steering is None else c(steering, dtype=float),
           DIVIDED_DIFFERENCE_CLOSE, PHI1_SERIES, X, F)


#: The ``steering`` of a filter without extra states.
_NO_EXTRA = np.zeros(0)
