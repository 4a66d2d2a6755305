"""The UKF's block of samples in compiled loops (numba): every sigma point's steps, outputs, gate and sums.

The UKF advances each of its 2n sigma points through every sample of a block with the point's own
zero-order-hold steps (filters/ukf.py). Done with numpy, that was a (points × samples × 7 × 7) complex
product for the steps (:meth:`online_id.model.discretise.SpectralForm.transitions`) and a dozen small
einsum calls per sample: 90 % of the UKF's time on the built-in run. Here the same arithmetic runs in a few
compiled calls per run of samples:

* :func:`sigma_expm_steps`: the same Φ from each point's generator G itself, expm(G h) + Σ_k c_k L_k(h) by a
  Padé approximant (:func:`online_id.model.compiled.expm_frechet`), without the eigen-decomposition: for a
  run of samples at a few periods (a log at one rate), where each point needs one Φ per period and speed;
* :func:`sigma_steps`: Φ = Re(Q (diag(e^(λ dt)) + D(dt) ∘ Σ_k c_k W_k) Q⁻¹) of every point at every sample
  from its eigen-decomposition (a log whose period jitters: many periods from one decomposition; the
  formulas, the divided differences D and their series near coalescing eigenvalues are those of
  :meth:`~online_id.model.discretise.SpectralForm.weights` and ``transitions``);
* :func:`step_plan`: a sample whose speed is the previous one's and whose period is too, within the EKF's
  :data:`~online_id.filters.local_model.SAMPLE_PERIOD_TOLERANCE` (time stamps k·dt differ in their last
  bits), reuses its Φ: each sample's row among the distinct steps (a constant-speed run at one rate has one);
* :func:`sigma_pass`: x ← Ad x + Bd (δ + g·e) per point, its outputs C x + D (δ + g·e) + M e (less a delay's
  Δτ·ẏ), the gate of each channel against the points' spread, and the sums of the accepted outputs.

Compiled at first use and cached on disk (online_id/util/jit.py); ``tests/test_array_path.py`` checks them
against the numpy forms.
"""

from __future__ import annotations

import numpy as np

from online_id.model.compiled import expm_frechet
from online_id.util.jit import cached_njit

#: As :data:`online_id.model.discretise.DIVIDED_DIFFERENCE_CLOSE` and ``PHI1_SERIES``.
_CLOSE = 1e-3
_C0, _C1, _C2, _C3 = 1 / 2, 1 / 6, 1 / 24, 1 / 120


@cached_njit()
def sigma_steps(lam, Q, Qi, W, dt, c, period_tolerance, Ad, Bd):  # pragma: no cover -- compiled
    """Fill Ad (S, m, ns, ns) and Bd (S, m, ns) with the top rows of Φ of each point (S) at each sample (m).

    ``lam`` (S, n), ``Q``, ``Qi`` (S, n, n), ``W`` (S, K, n, n), complex; ``dt`` (m,) periods [s]; ``c`` (m, K)
    the coefficients of the directions (first order in them); n = ns + 1 (the held input). A sample whose
    period is within ``period_tolerance`` (relative) of the previous sample's and whose coefficients are the
    same takes the previous sample's Φ.
    """
    S, n = lam.shape
    ns = n - 1
    K = W.shape[1]
    m = dt.shape[0]
    e = np.empty(n, dtype=np.complex128)
    M = np.empty((n, n), dtype=np.complex128)
    T = np.empty((ns, n), dtype=np.complex128)
    for s in range(S):
        for k in range(m):
            same = k > 0 and abs(dt[k] - dt[k - 1]) <= period_tolerance * dt[k - 1]
            if same:
                for i in range(K):
                    if c[k, i] != c[k - 1, i]:
                        same = False
            if same:
                Ad[s, k] = Ad[s, k - 1]
                Bd[s, k] = Bd[s, k - 1]
                continue
            h = dt[k]
            for a in range(n):
                e[a] = np.exp(lam[s, a] * h)
            for a in range(n):
                mu_a = lam[s, a] * h
                for b in range(n):
                    z = mu_a - lam[s, b] * h
                    if abs(z) < _CLOSE:
                        d = e[b] * (1 + z * (_C0 + z * (_C1 + z * (_C2 + z * _C3))))
                    else:
                        d = (e[a] - e[b]) / z
                    cw = 0j
                    for i in range(K):
                        cw += c[k, i] * W[s, i, a, b]
                    M[a, b] = h * d * cw
                M[a, a] += e[a]
            for a in range(ns):
                for b in range(n):
                    acc = 0j
                    for j in range(n):
                        acc += Q[s, a, j] * M[j, b]
                    T[a, b] = acc
            for a in range(ns):
                for b in range(n):
                    acc = 0.0
                    for j in range(n):
                        acc += T[a, j].real * Qi[s, j, b].real - T[a, j].imag * Qi[s, j, b].imag
                    if b < ns:
                        Ad[s, k, a, b] = acc
                    else:
                        Bd[s, k, a] = acc


@cached_njit()
def sigma_expm_steps(G, dG, dt, c, period_tolerance, Ad, Bd):  # pragma: no cover -- compiled
    """Φ of each point (S) at each of m steps, as :func:`sigma_steps` fills them, from each point's
    G = [[Ac, Bc], [0, 0]] itself, without its eigen-decomposition: Φ = expm(G h) + Σ_k c_k L_k(h), L_k the
    Fréchet derivative of expm at G h in direction dG_k h (both by scaling and squaring a Padé approximant,
    :func:`online_id.model.compiled.expm_frechet`; the same quantities as the spectral form's, to round-off).

    ``G`` (S, n, n), ``dG`` (S, K, n, n) real; ``dt`` (m,) periods [s], ``c`` (m, K) the coefficients of the
    directions; ``Ad`` (S, m, ns, ns), ``Bd`` (S, m, ns) filled, n = ns + 1. A point's expm and derivatives
    are formed once for each run of steps within ``period_tolerance`` (relative) of the period they were
    formed at (a derivative only in a direction some step's coefficient uses); each step's Φ is then their
    sum with its coefficients. (The caller leaves out a step the same as the one before: :func:`step_rows`.)
    """
    S, n = G.shape[0], G.shape[1]
    ns = n - 1
    K = dG.shape[1]
    m = dt.shape[0]
    used = np.zeros(K, dtype=np.bool_)
    for k in range(m):
        for i in range(K):
            if c[k, i] != 0.0:
                used[i] = True
    n_used = 0
    for i in range(K):
        if used[i]:
            n_used += 1
    X = np.empty((n, n))
    E = np.empty((n_used, n, n))
    F = np.empty((n, n))
    L = np.empty((n_used, n, n))
    cu = np.empty((m, n_used))
    j = 0
    for i in range(K):
        if used[i]:
            for k in range(m):
                cu[k, j] = c[k, i]
            j += 1
    for s in range(S):
        h_table = -1.0
        for k in range(m):
            if h_table < 0 or abs(dt[k] - h_table) > period_tolerance * h_table:
                h_table = dt[k]
                for a in range(n):
                    for b in range(n):
                        X[a, b] = G[s, a, b] * h_table
                j = 0
                for i in range(K):
                    if used[i]:
                        for a in range(n):
                            for b in range(n):
                                E[j, a, b] = dG[s, i, a, b] * h_table
                        j += 1
                expm_frechet(X, E, F, L)
            for a in range(ns):
                for b in range(n):
                    v = F[a, b]
                    for i in range(n_used):
                        v += cu[k, i] * L[i, a, b]
                    if b < ns:
                        Ad[s, k, a, b] = v
                    else:
                        Bd[s, k, a] = v


@cached_njit()
def step_plan(dt, c, period_tolerance, rows):  # pragma: no cover -- compiled
    """For m samples of periods ``dt`` (m,) and coefficients ``c`` (m, K): fills ``rows`` (m,) (int64) with the
    row of each sample's Φ among the distinct steps, from 0: a sample whose period is within
    ``period_tolerance`` (relative) of the previous sample's and whose coefficients are the same takes the
    previous sample's Φ, as in :func:`sigma_steps` (a constant-speed run at one rate has one row). Returns the
    number of rows and the number of runs of one period (each sample's period against the previous one's)."""
    m, K = c.shape
    n_rows = 1
    n_periods = 1
    if m > 0:
        rows[0] = 0
    for k in range(1, m):
        same_period = abs(dt[k] - dt[k - 1]) <= period_tolerance * dt[k - 1]
        same = same_period
        for i in range(K):
            if c[k, i] != c[k - 1, i]:
                same = False
        if not same_period:
            n_periods += 1
        if not same:
            n_rows += 1
        rows[k] = n_rows - 1
    return n_rows, n_periods


def step_rows(dt: np.ndarray, c: np.ndarray, period_tolerance: float) -> np.ndarray:
    """The rows of :func:`step_plan` alone."""
    rows = np.empty(len(dt), dtype=np.int64)
    step_plan(np.ascontiguousarray(dt, dtype=float), np.ascontiguousarray(c, dtype=float), period_tolerance, rows)
    return rows


@cached_njit()
def sigma_pass(Ad, Bd, row, X, delta, delta_now, observed, values, mask, C, D, shift, y_offset, lag, rate_C,
               rate_D, Wm, Wc, R, gate2, sum_y, sum_z, n_acc, rejected):  # pragma: no cover -- compiled
    """Advance every point X (S, ns) through the m samples (in place), sample k by its step ``row[k]`` of Ad, Bd
    (S, ·, ns, ns), (S, ·, ns), and at each ``observed``
    sample gate and sum the outputs: ``sum_y`` (S, p) += each point's accepted outputs, ``sum_z`` (p,) += the
    accepted values, ``n_acc`` (p,) += 1 per accepted channel, ``rejected`` (p,) += 1 per rejected one.

    Per sample: ``delta`` the held road-wheel angle, ``delta_now`` the sample's own, ``values`` (m, p),
    ``mask`` (m, p) the usable channels. Per point: ``C`` (S, p, ns), ``D`` (S, p), ``shift`` (S,) g·e,
    ``y_offset`` (S, p) M e, ``lag`` (S, p) Δτ of each channel (zero without a delay), ``rate_C`` (S, p, ns) and
    ``rate_D`` (S, p) the rate ẏ's matrices; ``Wm``, ``Wc`` the weights; ``R`` (p,) the channels' variance.
    """
    S, ns = X.shape
    p = C.shape[1]
    m = delta.shape[0]
    x_new = np.empty(ns)
    Y = np.empty((S, p))
    for k in range(m):
        r = row[k]
        for s in range(S):
            u = delta[k] + shift[s]
            for a in range(ns):
                acc = 0.0
                for b in range(ns):
                    acc += Ad[s, r, a, b] * X[s, b]
                x_new[a] = acc + Bd[s, r, a] * u
            for a in range(ns):
                X[s, a] = x_new[a]
        if not observed[k]:
            continue
        for s in range(S):
            u = delta_now[k] + shift[s]
            for i in range(p):
                acc = 0.0
                for b in range(ns):
                    acc += C[s, i, b] * X[s, b]
                y = acc + D[s, i] * u + y_offset[s, i]
                if lag[s, i] != 0.0:
                    rate = 0.0
                    for b in range(ns):
                        rate += rate_C[s, i, b] * X[s, b]
                    y -= lag[s, i] * (rate + rate_D[s, i] * u)
                Y[s, i] = y
        for i in range(p):
            if not mask[k, i]:
                for s in range(S):  # (as numpy's sums of the outputs times 0: a NaN output still shows)
                    sum_y[s, i] += Y[s, i] * 0.0
                continue
            yp = 0.0
            for s in range(S):
                yp += Wm[s] * Y[s, i]
            var = 0.0
            for s in range(S):
                var += Wc[s] * (Y[s, i] - yp) ** 2
            var += R[i]
            r = values[k, i] - yp
            if r * r <= gate2 * var:
                for s in range(S):
                    sum_y[s, i] += Y[s, i]
                sum_z[i] += values[k, i]
                n_acc[i] += 1.0
            else:
                for s in range(S):
                    sum_y[s, i] += Y[s, i] * 0.0
                rejected[i] += 1


def compile_now(n_points: int = 2) -> None:
    """Compile (or load from numba's disk cache) the loops now, with the types the UKF passes: a live run must
    not stall at its first block (as the EKF's :func:`~online_id.filters.local_model.compile_now`)."""
    S, m, n, p = n_points, 1, 6, 4
    lam = np.zeros((S, n + 1), dtype=np.complex128)
    Q = np.zeros((S, n + 1, n + 1), dtype=np.complex128)
    for s in range(S):
        for a in range(n + 1):
            Q[s, a, a] = 1.0
    Ad, Bd = np.empty((S, m, n, n)), np.empty((S, m, n))
    sigma_steps(lam, Q, Q.copy(), np.zeros((S, 1, n + 1, n + 1), dtype=np.complex128), np.full(m, 1e-3),
                np.zeros((m, 1)), 1e-9, Ad, Bd)
    step_plan(np.full(m, 1e-3), np.zeros((m, 1)), 1e-9, np.empty(m, dtype=np.int64))
    sigma_expm_steps(np.zeros((S, n + 1, n + 1)), np.zeros((S, 1, n + 1, n + 1)), np.full(m, 1e-3), np.zeros((m, 1)),
                     1e-9, Ad, Bd)
    z = np.zeros
    sigma_pass(Ad, Bd, np.zeros(m, dtype=np.int64), z((S, n)), z(m), z(m), np.ones(m, dtype=bool), z((m, p)),
               np.ones((m, p), dtype=bool), z((S, p, n)), z((S, p)), z(S), z((S, p)), z((S, p)), z((S, p, n)),
               z((S, p)), np.full(S, 1 / S), np.full(S, 1 / S), np.ones(p), 25.0, z((S, p)), z(p), z(p),
               z(p, dtype=np.int64))
