"""The UKF's block of samples in compiled loops (numba): every sigma point's steps, outputs, gate and sums.

The UKF advances each of its 2n sigma points through every sample of a block with the point's own
exact steps (filters/ukf.py). Done with numpy, that was a (points × samples × 7 × 7) complex
product for the steps (:meth:`online_id.model.discretise.SpectralForm.transitions`) and a dozen small
einsum calls per sample: 90 % of the UKF's time on the built-in run. Here the same arithmetic runs in a few
compiled calls per run of samples.

A step of period h carries the state by x ← Ad x + Γ w, w (4,) the step's input (the road-wheel angle's value
and derivatives in normalised time, :mod:`online_id.model.intersample`) and Γ its q input columns,

    Γ_j = h φ_j+1(Ac h) Bc = [φ_j(G h)]_{0:6, 6},   G = [[Ac, Bc], [0, 0]],   Γ_0 = Bd,

q = 1 for the zero-order hold ("hold": the Φ = expm(G h) of before issue 36, the same numbers), 2 for the
first-order hold, 4 for the cubic; each first order in the speed's distance c from the run's reference, as Φ:

* :func:`sigma_expm_steps`: from each point's generator itself, expm(X) + Σ_k c_k L_k by a Padé approximant
  (:func:`online_id.model.compiled.expm_frechet`), without the eigen-decomposition: X = G h for the hold,
  else the generator augmented with the input's chain (intersample.generator in normalised time, its ones
  scaled by 2⁻⁶: exact to round-off in every column, 1e-14 of it against an extended-precision expm); for a
  run of samples at a few periods (a log at one rate), where each point needs one Φ per period and speed;
* :func:`sigma_steps`: Φ = Re(Q (diag(e^(λ dt)) + D(dt) ∘ Σ_k c_k W_k) Q⁻¹) of every point at every sample
  from its eigen-decomposition (a log whose period jitters: many periods from one decomposition; the
  formulas, the divided differences D and their series near coalescing eigenvalues are those of
  :meth:`~online_id.model.discretise.SpectralForm.weights` and ``transitions``), and Γ_j mode by mode, each
  φ_j(λ h) on its own and the divided differences φ_j[μ_a, μ_b] of the first-order term by their series or
  recurrence (:func:`_phi_columns`; never the recurrence Γ_j = (Ac h)⁻¹ (Γ_j−1 − h Bc/j!), which loses the
  digits of a slow mode): 3e-13 of each column at eigenvector conditions up to 7e3;
* :func:`step_plan`: a sample whose speed is the previous one's and whose period is too, within the EKF's
  :data:`~online_id.filters.local_model.SAMPLE_PERIOD_TOLERANCE` (time stamps k·dt differ in their last
  bits), reuses its Φ: each sample's row among the distinct steps (a constant-speed run at one rate has one);
* :func:`sigma_pass`: x ← Ad x + Γ_0 (w_0 + g·e) + Σ_j Γ_j w_j per point (the extra states' steering shift g·e
  moves the curve's value only), its outputs C x + D (δ + g·e) + M e at the sample's own δ (less a delay's
  Δτ·ẏ), the gate of each channel against the points' spread, and the sums of the accepted outputs.

Compiled at first use and cached on disk (online_id/util/jit.py); ``tests/test_array_path.py`` checks them
against the numpy forms, ``tests/test_intersample_filters.py`` the input columns against
:mod:`online_id.model.intersample`'s references.
"""

from __future__ import annotations

import math

import numpy as np

from online_id.model.compiled import expm_frechet
from online_id.util.jit import cached_njit

#: As :data:`online_id.model.discretise.DIVIDED_DIFFERENCE_CLOSE` and ``PHI1_SERIES``.
_CLOSE = 1e-3
_C0, _C1, _C2, _C3 = 1 / 2, 1 / 6, 1 / 24, 1 / 120


#: 1/n!, n = 0 … 39 (the φ-functions' series).
_INV_FACTORIAL = np.array([1.0 / math.factorial(n) for n in range(40)])
#: The series of φ_j and of their divided differences stop once a term's bound is below this (their values
#: are at least 0.02 where the series is taken: relative truncation under 1e-17).
_SERIES_TOLERANCE = 1e-19
#: The series where every argument is below this in modulus, the recurrence φ_j+1 = (φ_j − 1/j!)/μ above it
#: (under one digit lost a step), as :func:`online_id.model.intersample.phi_functions`.
_SERIES_RADIUS = 1.0
#: The input chain's ones in the augmented generator of :func:`sigma_expm_steps`, scaled by 2⁻⁶ (a power of
#: two: the scaling back of Γ_j by 2⁶ʲ is exact). With ones the generator's 1-norm is at least 1, which asks
#: the Padé approximant for degree 9 at 1 kHz; 2⁻⁶ lies above the degree-3 bound (1.5e-2), where column j,
#: whose leading term is the (j + 1)-th power of the generator, would keep only 6 − j orders of the 7.
_CHAIN = 2.0 ** -6


@cached_njit()
def _phi_scalar(z, q, out):  # pragma: no cover -- compiled
    """out[j] = φ_j(z), j = 0 … q − 1, of one complex z: the recurrence from e^z where |z| ≥ 1, else each
    series Σ_n zⁿ/(n + j)!."""
    if abs(z) >= _SERIES_RADIUS:
        out[0] = np.exp(z)
        for j in range(1, q):
            out[j] = (out[j - 1] - _INV_FACTORIAL[j - 1]) / z
        return
    for j in range(q):
        term = _INV_FACTORIAL[j] + 0j
        acc = term
        for n in range(1, 30):
            term = term * z / (n + j)
            acc += term
            if abs(term.real) + abs(term.imag) < _SERIES_TOLERANCE:
                break
        out[j] = acc


@cached_njit()
def _phi_divided(a, b, d0, phi_a, phi_b, q, out):  # pragma: no cover -- compiled
    """out[j] = φ_j[a, b] = (φ_j(a) − φ_j(b))/(a − b) (φ_j'(a) where a = b), j = 1 … q − 1, of complex a, b.

    Where |a| or |b| ≥ 1: φ_j+1[a, b] = (φ_j[a, b] − φ_j+1(b))/a from ``d0`` = φ_0[a, b] (the exponential's
    divided difference), dividing by the larger in modulus (``phi_a``, ``phi_b`` their φ_j). Else the series
    φ_j[a, b] = Σ_{n ≥ 1} h_n−1(a, b)/(n + j)!, h_m = Σ_{i ≤ m} aⁱ b^(m−i) (= (aⁿ − bⁿ)/(a − b), n = m + 1),
    |h_m| ≤ (m + 1) rᵐ, r = max(|a|, |b|): no difference taken, so nothing cancels where a and b are close."""
    ra, rb = abs(a), abs(b)
    if ra >= _SERIES_RADIUS or rb >= _SERIES_RADIUS:
        if ra >= rb:
            p, other = a, phi_b
        else:
            p, other = b, phi_a
        prev = d0
        for j in range(1, q):
            prev = (prev - other[j]) / p
            out[j] = prev
        return
    r = max(ra, rb)
    for j in range(1, q):
        out[j] = 0j
    h = 1.0 + 0j  # h_0
    a_pow = 1.0 + 0j
    bound = 1.0  # n r^(n−1) for n = 1
    for n in range(1, 30):
        for j in range(1, q):
            out[j] += h * _INV_FACTORIAL[n + j]
        a_pow = a_pow * a
        h = b * h + a_pow  # h_n, of the next term
        bound = bound * r * (n + 1) / n
        if bound * _INV_FACTORIAL[n + 2] < _SERIES_TOLERANCE:  # the next term's bound (and the tail's, near it)
            break


@cached_njit()
def _phi_columns(lam, Q, Qi, CW, D0, h, q, out):  # pragma: no cover -- compiled
    """Γ_j, j = 0 … q − 1, into ``out`` (ns, q): the top-right column of φ_j(G h) with its first-order term, as

        Γ_j = h [φ_j+1(G h) G]_{0:ns, ns}
            = h Re(Q (φ_j+1(μ) ∘ u + h (φ_j+1[μ_a, μ_b] ∘ CW) u + φ_j+1(μ) ∘ (CW v)))_{0:ns}

    (φ_j(z) = 1/j! + z φ_j+1(z); u = Q⁻¹ G e_ns = λ ∘ v, v = Q⁻¹'s last column, the input's; μ = λ h). Written
    so, the input's own mode (λ = 0) drops out exactly: the top-right column of Q φ_j(Λ h) Q⁻¹ sums terms of
    order one to a result of order h (it lost 1e-16 · cond / h of it: 7e-11 at 10 kHz). ``lam`` (n,), ``Q``,
    ``Qi`` (n, n) one point's decomposition; ``CW`` (n, n) Σ_k c_k W_k; ``D0`` (n, n) the exponential's divided
    differences (:func:`sigma_steps`' d)."""
    n = lam.shape[0]
    ns = n - 1
    mu = np.empty(n, dtype=np.complex128)
    phi = np.empty((n, q + 1), dtype=np.complex128)
    u = np.empty(n, dtype=np.complex128)
    cv = np.empty(n, dtype=np.complex128)  # CW v
    for a in range(n):
        mu[a] = lam[a] * h
        _phi_scalar(mu[a], q + 1, phi[a])
        u[a] = lam[a] * Qi[a, ns]
        acc = 0j
        for b in range(n):
            acc += CW[a, b] * Qi[b, ns]
        cv[a] = acc
    DD = np.empty((q + 1, n, n), dtype=np.complex128)
    dd = np.empty(q + 1, dtype=np.complex128)
    for a in range(n):
        for b in range(a, n):
            _phi_divided(mu[a], mu[b], D0[a, b], phi[a], phi[b], q + 1, dd)
            for j in range(1, q + 1):
                DD[j, a, b] = dd[j]
                DD[j, b, a] = dd[j]
    y = np.empty(n, dtype=np.complex128)
    for j in range(q):
        for a in range(n):
            acc = 0j
            for b in range(n):
                acc += DD[j + 1, a, b] * CW[a, b] * u[b]
            y[a] = phi[a, j + 1] * (u[a] + cv[a]) + h * acc
        for r in range(ns):
            acc = 0.0
            for a in range(n):
                acc += Q[r, a].real * y[a].real - Q[r, a].imag * y[a].imag
            out[r, j] = h * acc


@cached_njit()
def sigma_steps(lam, Q, Qi, W, dt, c, period_tolerance, Ad, Gam):  # pragma: no cover -- compiled
    """Fill Ad (S, m, ns, ns) and the input columns Γ (S, m, ns, q) of each point (S) at each sample (m): Ad and
    Γ_0 = Bd the top rows of Φ, and for q > 1 Γ_j = [φ_j(G h)]_{0:ns, ns}, j = 1 … q − 1 (module docstring).

    ``lam`` (S, n), ``Q``, ``Qi`` (S, n, n), ``W`` (S, K, n, n), complex; ``dt`` (m,) periods [s]; ``c`` (m, K)
    the coefficients of the directions (first order in them); n = ns + 1 (the input). A sample whose
    period is within ``period_tolerance`` (relative) of the previous sample's and whose coefficients are the
    same takes the previous sample's Φ.
    """
    S, n = lam.shape
    ns = n - 1
    K = W.shape[1]
    m = dt.shape[0]
    q = Gam.shape[3]
    e = np.empty(n, dtype=np.complex128)
    M = np.empty((n, n), dtype=np.complex128)
    T = np.empty((ns, n), dtype=np.complex128)
    CW = np.empty((n, n), dtype=np.complex128)  # Σ_k c_k W_k of the sample (q > 1)
    D0 = np.empty((n, n), dtype=np.complex128)  # exp's divided differences (q > 1)
    for s in range(S):
        for k in range(m):
            same = k > 0 and abs(dt[k] - dt[k - 1]) <= period_tolerance * dt[k - 1]
            if same:
                for i in range(K):
                    if c[k, i] != c[k - 1, i]:
                        same = False
            if same:
                Ad[s, k] = Ad[s, k - 1]
                Gam[s, k] = Gam[s, k - 1]
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
                    if q > 1:
                        CW[a, b] = cw
                        D0[a, b] = d
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
                        Gam[s, k, a, 0] = acc
            if q > 1:
                _phi_columns(lam[s], Q[s], Qi[s], CW, D0, h, q, Gam[s, k])


@cached_njit()
def sigma_expm_steps(G, dG, dt, c, period_tolerance, Ad, Gam):  # pragma: no cover -- compiled
    """Ad and Γ of each point (S) at each of m steps, as :func:`sigma_steps` fills them, from each point's
    G = [[Ac, Bc], [0, 0]] itself, without its eigen-decomposition: Φ = expm(X) + Σ_k c_k L_k, L_k the Fréchet
    derivative of expm at X in direction dG_k h (both by scaling and squaring a Padé approximant,
    :func:`online_id.model.compiled.expm_frechet`; the same quantities as the spectral form's, to round-off).

    X is G h, and for q > 1 input columns the augmented generator of the input's chain (ns + q square):

        X = [[Ac h, Bc h, 0 …], [0, 0, ε, 0 …], …, [0 …, 0]],   expm(X)[0:ns, ns + j] = ε^j Γ_j,

    ε = 2⁻⁶ (:data:`_CHAIN`; :func:`online_id.model.intersample.generator` in normalised time, its ones scaled);
    with q = 1 it is G h, the hold's.

    ``G`` (S, n, n), ``dG`` (S, K, n, n) real; ``dt`` (m,) periods [s], ``c`` (m, K) the coefficients of the
    directions; ``Ad`` (S, m, ns, ns), ``Gam`` (S, m, ns, q) filled, n = ns + 1. A point's expm and derivatives
    are formed once for each run of steps within ``period_tolerance`` (relative) of the period they were
    formed at (a derivative only in a direction some step's coefficient uses); each step's Φ is then their
    sum with its coefficients. (The caller leaves out a step the same as the one before: :func:`step_rows`.)
    """
    S, n = G.shape[0], G.shape[1]
    ns = n - 1
    K = dG.shape[1]
    m = dt.shape[0]
    q = Gam.shape[3]
    N = ns + q
    scale = np.empty(q)  # ε^-j
    for j in range(q):
        scale[j] = (1.0 / _CHAIN) ** j
    used = np.zeros(K, dtype=np.bool_)
    for k in range(m):
        for i in range(K):
            if c[k, i] != 0.0:
                used[i] = True
    n_used = 0
    for i in range(K):
        if used[i]:
            n_used += 1
    X = np.zeros((N, N))
    for j in range(q - 1):
        X[ns + j, ns + j + 1] = _CHAIN
    E = np.zeros((n_used, N, N))
    F = np.empty((N, N))
    L = np.empty((n_used, N, N))
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
                for b in range(N):
                    v = F[a, b]
                    for i in range(n_used):
                        v += cu[k, i] * L[i, a, b]
                    if b < ns:
                        Ad[s, k, a, b] = v
                    else:
                        Gam[s, k, a, b - ns] = v * scale[b - ns]


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
def sigma_pass(Ad, Gam, row, X, w, delta_now, observed, values, mask, C, D, shift, y_offset, lag, rate_C,
               rate_D, Wm, Wc, R, gate2, sum_y, sum_z, n_acc, rejected):  # pragma: no cover -- compiled
    """Advance every point X (S, ns) through the m samples (in place), sample k by its step ``row[k]`` of Ad, Γ
    (S, ·, ns, ns), (S, ·, ns, q): x ← Ad x + Γ_0 (w_0 + g·e) + Σ_{j=1}^{q−1} Γ_j w_j, and at each ``observed``
    sample gate and sum the outputs: ``sum_y`` (S, p) += each point's accepted outputs, ``sum_z`` (p,) += the
    accepted values, ``n_acc`` (p,) += 1 per accepted channel, ``rejected`` (p,) += 1 per rejected one.

    Per sample: ``w`` (m, ≥ q) the step's input (road-wheel angle [rad] and its derivatives in normalised time,
    :mod:`online_id.model.intersample`; the hold's [δ, 0, 0, 0]), ``delta_now`` the sample's own angle,
    ``values`` (m, p), ``mask`` (m, p) the usable channels. Per point: ``C`` (S, p, ns), ``D`` (S, p), ``shift``
    (S,) g·e, ``y_offset`` (S, p) M e, ``lag`` (S, p) Δτ of each channel (zero without a delay), ``rate_C``
    (S, p, ns) and ``rate_D`` (S, p) the rate ẏ's matrices; ``Wm``, ``Wc`` the weights; ``R`` (p,) the channels'
    variance.
    """
    S, ns = X.shape
    p = C.shape[1]
    m = w.shape[0]
    q = Gam.shape[3]
    x_new = np.empty(ns)
    Y = np.empty((S, p))
    for k in range(m):
        r = row[k]
        for s in range(S):
            u = w[k, 0] + shift[s]
            for a in range(ns):
                acc = 0.0
                for b in range(ns):
                    acc += Ad[s, r, a, b] * X[s, b]
                x_new[a] = acc + Gam[s, r, a, 0] * u
                for j in range(1, q):
                    x_new[a] += Gam[s, r, a, j] * w[k, j]
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
    Ad, Gam = np.empty((S, m, n, n)), np.empty((S, m, n, 1))
    sigma_steps(lam, Q, Q.copy(), np.zeros((S, 1, n + 1, n + 1), dtype=np.complex128), np.full(m, 1e-3),
                np.zeros((m, 1)), 1e-9, Ad, Gam)
    step_plan(np.full(m, 1e-3), np.zeros((m, 1)), 1e-9, np.empty(m, dtype=np.int64))
    sigma_expm_steps(np.zeros((S, n + 1, n + 1)), np.zeros((S, 1, n + 1, n + 1)), np.full(m, 1e-3), np.zeros((m, 1)),
                     1e-9, Ad, Gam)
    z = np.zeros
    sigma_pass(Ad, Gam, np.zeros(m, dtype=np.int64), z((S, n)), z((m, 4)), z(m), np.ones(m, dtype=bool), z((m, p)),
               np.ones((m, p), dtype=bool), z((S, p, n)), z((S, p)), z(S), z((S, p)), z((S, p)), z((S, p, n)),
               z((S, p)), np.full(S, 1 / S), np.full(S, 1 / S), np.ones(p), 25.0, z((S, p)), z(p), z(p),
               z(p, dtype=np.int64))
