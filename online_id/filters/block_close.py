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
    if n > 6:  # the group's and the block's small products, for the 5 output channels and P parameters
        n_out, P_ = 5, n - 6
        C_out, D = np.zeros((n_out, 6)), np.zeros(n_out)
        X, F3 = np.zeros((2, 6)), np.zeros((2, 6, n))
        H = output_sensitivity(C_out, np.zeros((n_out * P_, 6)), np.zeros((n_out, P_)), F3[1], X[1], 0.0)
        gate_threshold(H, P, D, 1.0)
        for mask in _masks(n_out):
            accept_group(C_out, D, D, X, F3, np.zeros((1, n_out)), np.zeros(1), D, mask)
        first_order(D, np.zeros((P_ + 1, n_out)), np.zeros(P_), 0.0)
        state_fault(np.zeros(n), P, np.ones(n, dtype=np.bool_), 6, P_, 1.0, 1.0)
        outputs_at(C_out, D, np.zeros((n_out * P_, 6)), np.zeros((n_out, P_)), np.zeros(P_))
        adapt_r(np.ones(1), np.zeros(1, dtype=np.int64), np.ones(n_out), np.ones(n_out), np.ones(n_out), 1.0, 1.0,
                1.0, 1.0)
        book_block(np.zeros(1, dtype=np.int64), np.ones(1), np.ones(1), 4, 1.0, np.zeros(n_out), np.zeros(n_out), 1.0,
                   np.zeros(2 + 2 * n_out), 0.0, 0.0, np.ones(n_out), np.ones(n_out))
        listen(np.zeros(n_out, dtype=np.bool_), np.zeros(1, dtype=np.int64), np.zeros(n_out), 0.0)
        book_adapt_listen(np.zeros(1, dtype=np.int64), np.ones(1), np.ones(1), 4, 1.0, np.zeros(n_out),
                          np.zeros(n_out), 1.0, np.zeros(2 + 2 * n_out), 0.0, 0.0, np.ones(n_out), np.ones(n_out), True,
                          np.ones(n_out), 1.0, 1.0, 1.0, np.zeros(n_out, dtype=np.bool_), np.zeros(n_out), np.zeros(n),
                          P, np.ones(n, dtype=np.bool_), 6, P_, 1.0, 1.0)


# -- a group's and a block's small products (issue 36: the 100 Hz cost) ---------------------------------------
# At 100 Hz each correction's block is 5 samples: the arithmetic below is a few hundred flops, numpy's calls for
# it cost more than the flops (a few microseconds each, a dozen a block). These loops are the same expressions;
# their sums run in another order than numpy's matrix-vector products (round-off, 1e-16 relative).


@cached_njit()
def output_sensitivity(C, dC, dD, F_x, x, delta):  # pragma: no cover -- compiled
    """H (n_out, N) = C F_x, plus (dC x).reshape(n_out, P) + dD δ in the parameters' columns 6 … 6 + P − 1
    (:meth:`LinearOutputs.sensitivity <online_id.filters.local_model.LinearOutputs.sensitivity>` without extra
    states): ``C`` (n_out, 6), ``dC`` (n_out · P, 6), ``dD`` (n_out, P), ``F_x`` (6, N), ``x`` (6,)."""
    n_out, P = dD.shape
    n = F_x.shape[0]
    H = np.ascontiguousarray(C) @ np.ascontiguousarray(F_x)
    for o in range(n_out):
        for p in range(P):
            acc = 0.0
            for b in range(n):
                acc += dC[o * P + p, b] * x[b]
            H[o, n + p] += acc + dD[o, p] * delta
    return H


@cached_njit()
def gate_threshold(H, P, R, gate_sq):  # pragma: no cover -- compiled
    """Each channel's gate on a squared residual: gate² (diag(H P Hᵀ) + R), ``H`` (n_out, N), ``P`` (N, N)."""
    n_out, N = H.shape
    out = np.empty(n_out)
    for o in range(n_out):
        acc = 0.0
        for a in range(N):
            t = 0.0
            for b in range(N):
                t += H[o, b] * P[b, a]
            acc += t * H[o, a]
        out[o] = gate_sq * (acc + R[o])
    return out


@cached_njit()
def accept_group(C, D, offset, X, F, values, deltas, threshold, mask):  # pragma: no cover -- compiled
    """A group whose every sample was observed under one channel ``mask``: whether every usable channel of every
    sample passes its gate (r² ≤ threshold; a NaN residual does not), and if so the sums the block keeps
    (filters/block_sums.py ``add_accepted``): Σ values (every channel, as numpy's sum), Σ F_x (6, N) and Σ x (6,)
    over the samples after the group's start (``X`` (m + 1, 6), ``F`` (m + 1, 6, N)), Σ δ. When a sample fails,
    False and zeros: the caller works the group sample by sample."""
    m, n_out = values.shape
    n, N = F.shape[1], F.shape[2]
    sum_z = np.zeros(n_out)
    sum_F = np.zeros((n, N))
    sum_x = np.zeros(n)
    sum_delta = 0.0
    for j in range(m):
        for o in range(n_out):
            if not mask[o]:
                continue
            y = 0.0
            for b in range(n):
                y += C[o, b] * X[j + 1, b]
            y += D[o] * deltas[j] + offset[o]
            r = values[j, o] - y
            if not r * r <= threshold[o]:
                return False, sum_z, sum_F, sum_x, 0.0
    for j in range(m):
        for o in range(n_out):
            sum_z[o] += values[j, o]
        for b in range(n):
            sum_x[b] += X[j + 1, b]
            for c in range(N):
                sum_F[b, c] += F[j + 1, b, c]
        sum_delta += deltas[j]
    return True, sum_z, sum_F, sum_x, sum_delta


@cached_njit()
def first_order(base, L, ds, dV):  # pragma: no cover -- compiled
    """base + Σ_i ds_i L_i + dV L_P: a table's entries at log-scale parameter offsets ``ds`` (P,) and a speed
    offset ``dV`` (filters/local_model.py ``LocalModel.step``); ``base`` (k,), ``L`` (P + 1, k)."""
    P = ds.shape[0]
    out = base.copy()
    for i in range(P):
        for a in range(out.shape[0]):
            out[a] += ds[i] * L[i, a]
    for a in range(out.shape[0]):
        out[a] += dV * L[P, a]
    return out


@cached_njit()
def state_fault(x, P, free, first_param, n_params, max_var, max_log_scale):  # pragma: no cover -- compiled
    """What is broken in a corrected state, as the health check's order of tests (filters/health.py ``check``):
    0 nothing, 1 a NaN or an inf in ``x`` or ``P``, 2 a non-positive variance of a state ``free`` (bool (N,)) to
    have one, 3 a parameter's variance over ``max_var``, 4 a parameter's |x| over ``max_log_scale``; the
    parameters are x[first_param : first_param + n_params]."""
    N = x.shape[0]
    for a in range(N):
        if not np.isfinite(x[a]):
            return 1
        for b in range(N):
            if not np.isfinite(P[a, b]):
                return 1
    for a in range(N):
        if free[a] and P[a, a] <= 0.0:
            return 2
    for a in range(first_param, first_param + n_params):
        if P[a, a] > max_var:
            return 3
    for a in range(first_param, first_param + n_params):
        if abs(x[a]) > max_log_scale:
            return 4
    return 0


@cached_njit()
def outputs_at(C, D, dC, dD, ds):  # pragma: no cover -- compiled
    """C + Σ_i ds_i dC_i (n_out, 6) and D + dD ds (n_out,): linear outputs at log-scale offsets ``ds`` (P,)
    (filters/local_model.py ``LinearOutputs.at``; ``dC`` (n_out · P, 6), output-major)."""
    n_out, n = C.shape
    P = ds.shape[0]
    C2 = C.copy()
    D2 = D.copy()
    for o in range(n_out):
        for b in range(n):
            acc = 0.0
            for i in range(P):
                acc += dC[o * P + i, b] * ds[i]
            C2[o, b] += acc
        acc = 0.0
        for i in range(P):
            acc += dD[o, i] * ds[i]
        D2[o] += acc
    return C2, D2


@cached_njit()
def recurse_group(Ad, Gamma, columns, run_of, steering, w, X, F):  # pragma: no cover -- compiled
    """The recursion the tables unroll, sample by sample in one compiled loop (the same numbers to round-off):
    x_j = Ad_j x_j-1 + Γ_j w_j and F_j = Ad_j F_j-1 + [0 | J_j | Γ_j,0 gᵀ], filling X[1:] (m + 1, n) and F[1:]
    (m + 1, n, N) from X[0], F[0].

    ``Ad`` (m, n, n), ``Gamma`` (m, n, K) the input columns of each step's input ``w`` (m, K) (K = 1: the hold,
    Γ = Bd and w = δ; K = 4: an input polynomial, model/intersample.py); the parameters' columns
    J_j[:, i] = [x_j-1; w_j] · ``columns[run_of[j]]`` [:n + K, i·n:(i + 1)·n] (the (n + K, P·n) tables of
    filters/local_model.py, one per run of samples at one linearisation point); the extra states' columns
    Γ_j,0 gᵀ = Bd_j gᵀ (``steering`` g, (n_extra,): they shift the input's value only).
    """
    m, n, K = Gamma.shape
    N = F.shape[2]
    P = columns.shape[2] // n
    n_extra = steering.shape[0]
    z = np.empty(n + K)
    for j in range(m):
        for b in range(n):
            z[b] = X[j, b]
        for k in range(K):
            z[n + k] = w[j, k]
        table = columns[run_of[j]]
        for a in range(n):
            acc = 0.0
            for b in range(n):
                acc += Ad[j, a, b] * X[j, b]
            for k in range(K):
                acc += Gamma[j, a, k] * w[j, k]
            X[j + 1, a] = acc
            for c in range(N):
                acc = 0.0
                for b in range(n):
                    acc += Ad[j, a, b] * F[j, b, c]
                F[j + 1, a, c] = acc
            for i in range(P):
                acc = 0.0
                for r in range(n + K):
                    acc += z[r] * table[r, i * n + a]
                F[j + 1, a, n + i] += acc
            for k in range(n_extra):
                F[j + 1, a, n + P + k] += Gamma[j, a, 0] * steering[k]


@cached_njit()
def close_block(Phi0, L, columns, G0, LG, ds, dV, w, x, F0, C, D, dC, dD, values, deltas, mask, R, gate_sq, P, q,
                share):  # pragma: no cover -- compiled
    """An ordinary block's whole close in one call (filters/ekf.py ``_close_block``): the group's steps from a
    linearisation point's tables for one period, its mean and chained Jacobians (``recurse_group``'s
    recursion), the gate from its first sample, the block's sums and means, the covariance's predict, the
    block's covariances and the Joseph correction: the steps :meth:`EKFEstimator._catch_up`, ``_flush``,
    ``_block_innovation`` and ``_apply_correction`` take one by one, in the same order.

    Tables (filters/local_model.py ``LocalModel._tables``): ``Phi0`` (49,), ``L`` (P + 1, 49), ``columns``
    (6 + K, P · 6), the input polynomial's ``G0`` (6 · (K − 1),) and ``LG`` (P + 1, 6 · (K − 1)) (empty for the
    hold); ``ds`` (P,) the parameters' offset from the point, ``dV`` (m,) each step's speed offset, ``w`` (m, K)
    the steps' inputs; ``x`` (N,) the augmented mean at the block start (its model states the group's X[0]),
    ``F0`` (6, N) their chained Jacobian; the outputs at the parameters (``C``, ``D``, ``dC``, ``dD``); the
    samples' ``values`` (m, n_out) and ``deltas`` (m,) under one ``mask``; ``R`` (n_out,) the noise variances,
    ``gate_sq`` the gate in σ², ``P`` (N, N) the covariance at the block start, ``q`` (N,) the block's process
    noise and ``share`` the observations' share of it.

    Returns (status, x, P, ν, S): status 0 with the corrected mean and covariance, the innovation of the
    channels in ``mask`` and its covariance; else nothing is done (1: a sample failed its gate, 2: a block
    channel failed the block's gate, 3: a NaN or an inf in C or S) and the caller takes the steps one by one.
    """
    n = F0.shape[0]
    N = P.shape[0]
    m, K = w.shape
    Pn = ds.shape[0]
    n1 = n + 1
    J = K - 1
    n_out = C.shape[0]
    base = first_order(Phi0, L, ds, 0.0)
    gbase = first_order(G0, LG, ds, 0.0)
    Ad = np.empty((m, n, n))
    Gam = np.empty((m, n, K))
    for j in range(m):
        v = dV[j]
        for a in range(n):
            for b in range(n):
                Ad[j, a, b] = base[a * n1 + b] + v * L[Pn, a * n1 + b]
            Gam[j, a, 0] = base[a * n1 + n] + v * L[Pn, a * n1 + n]
            for k in range(J):
                Gam[j, a, k + 1] = gbase[a * J + k] + v * LG[Pn, a * J + k]
    X = np.empty((m + 1, n))
    F = np.empty((m + 1, n, N))
    X[0] = x[:n]
    F[0] = F0
    recurse_group(Ad, Gam, columns.reshape((1,) + columns.shape), np.zeros(m, dtype=np.int64), np.zeros(0), w, X,
                  F)
    empty = (np.zeros(0), np.zeros((0, 0)), np.zeros(0), np.zeros((0, 0)))
    H1 = output_sensitivity(C, dC, dD, F[1], X[1], deltas[0])
    threshold = gate_threshold(H1, P, R, gate_sq)
    ok, sum_z, sum_F, sum_x, sum_delta = accept_group(C, D, np.zeros(n_out), X, F, values, deltas, threshold, mask)
    if not ok:
        return 1, empty[0], empty[1], empty[2], empty[3]
    Hs = output_sensitivity(C, dC, dD, sum_F, sum_x, sum_delta)
    k_out = 0
    for o in range(n_out):
        k_out += mask[o]
    channels = np.empty(k_out, dtype=np.int64)
    k_out = 0
    for o in range(n_out):
        if mask[o]:
            channels[k_out] = o
            k_out += 1
    Hbar = np.empty((k_out, N))
    C_states = np.empty((k_out, n))
    nu = np.empty(k_out)
    R_over_n = np.empty(k_out)
    for i in range(k_out):
        o = channels[i]
        y = 0.0
        for b in range(n):
            y += C[o, b] * sum_x[b]
            C_states[i, b] = C[o, b]
        y += D[o] * sum_delta
        nu[i] = sum_z[o] / m - y / m
        R_over_n[i] = R[o] / m
        for c in range(N):
            Hbar[i, c] = Hs[o, c] / m
    Fb = np.eye(N)
    for b in range(n):
        for c in range(N):
            Fb[b, c] = F[m, b, c]
    P_pred = predict_covariance(Fb, P, q)
    Cc, S = block_covariances(Hbar, C_states, q * share, P, Fb, R_over_n)
    for i in range(k_out):
        if not nu[i] * nu[i] / S[i, i] <= gate_sq:
            return 2, empty[0], empty[1], empty[2], empty[3]
    if not all_finite(Cc, S):
        return 3, empty[0], empty[1], empty[2], empty[3]
    Kg, P_new = joseph_covariance(P_pred, Cc, S)
    x_new = x.copy()
    for b in range(n):
        x_new[b] = X[m, b]
    for a in range(N):
        acc = 0.0
        for i in range(k_out):
            acc += Kg[a, i] * nu[i]
        x_new[a] += acc
    return 0, x_new, P_new, nu, S


def compile_close(n_params: int, N: int, K: int, n_out: int = 5) -> None:
    """Compile (or load) :func:`close_block` now for P parameters, an N-long augmented state and K-long step
    inputs (a live run must not stall at its first correction). A block of one sample that fails its gate."""
    n, J = 6, K - 1
    z = np.zeros
    tables = (z((n + 1) ** 2), z((n_params + 1, (n + 1) ** 2)), z((n + K, n_params * n)), z(n * J),
              z((n_params + 1, n * J)))
    outputs = (z((n_out, n)), z(n_out), z((n_out * n_params, n)), z((n_out, n_params)))
    for mask in _masks(n_out):
        close_block(*tables, z(n_params), z(1), z((1, K)), z(N), z((n, N)), *outputs, np.full((1, n_out), np.nan),
                    z(1), mask, np.ones(n_out), 1.0, np.eye(N), z(N), 1.0)


@cached_njit()
def adapt_r(nis, channels, R_diag, R_nominal, nis_mean, r_temper, gate_sq, w, factor):  # pragma: no cover
    """Covariance matching's step (filters/health.py ``FilterHealth.adapt_r``) in place, for the block's
    ``channels``: the running mean of each channel's NIS (clipped at the gate), and R = R_nominal · max(1, mean)
    · ``factor``."""
    for i in range(channels.shape[0]):
        c = channels[i]
        v = nis[i] * R_diag[c] / R_nominal[c] / r_temper
        clipped = v if (v < gate_sq or v != v) else gate_sq  # (numpy's minimum and maximum: a NaN carries on)
        nis_mean[c] += w * (clipped - nis_mean[c])
        mean = nis_mean[c]
        R_diag[c] = R_nominal[c] * (mean if (mean > 1.0 or mean != mean) else 1.0) * factor


@cached_njit()
def book_block(channels, nu, var, vy, vy_scale, innovation_sq, innovation_n, gate_sq, row, time,
               converged, R_diag, R_nominal):  # pragma: no cover -- compiled
    """A correction's bookkeeping (filters/health.py ``FilterHealth.correct``) in one call, in place: each of the
    block's ``channels``' squared innovation (× ``vy_scale`` on channel ``vy``, the lateral velocity worked per unit
    speed, back to SI) and count, and the innovation log's ``row`` (time, converged, ν/√S per channel, R/R_nominal
    per channel, NaN elsewhere: filters/innovations.py); returns (NIS (m,), kept (m,) bool: NIS within the gate)."""
    m = channels.shape[0]
    nis = np.empty(m)
    keep = np.empty(m, dtype=np.bool_)
    row[:] = np.nan
    row[0] = time
    row[1] = converged
    n_channels = R_diag.shape[0]
    for i in range(m):
        c = channels[i]
        nu_sq = nu[i] ** 2
        nis[i] = nu_sq / var[i]
        innovation_sq[c] += nu_sq * (vy_scale if c == vy else 1.0)
        innovation_n[c] += 1
        keep[i] = nis[i] <= gate_sq
        row[2 + c] = nu[i] / np.sqrt(var[i])
        row[2 + n_channels + c] = R_diag[c] / R_nominal[c]
    return nis, keep


@cached_njit()
def listen(seen, kept, rejecting_since, time):  # pragma: no cover -- compiled
    """The health's ``listening`` (filters/health.py) in place: per channel measured in the block (``seen``) and not
    used by its correction (not in ``kept``, indices), the time its streak of unused blocks started (NaN: no
    streak); returns the longest streak [s]; ``seen`` cleared."""
    longest = 0.0
    for i in range(seen.shape[0]):
        used = False
        for j in range(kept.shape[0]):
            if kept[j] == i:
                used = True
        if not seen[i] or used:
            rejecting_since[i] = np.nan
            continue
        if rejecting_since[i] != rejecting_since[i]:
            rejecting_since[i] = time
        longest = max(longest, time - rejecting_since[i])
    seen[:] = False
    return longest


@cached_njit()
def book_adapt_listen(channels, nu, var, vy, vy_scale, innovation_sq, innovation_n, gate_sq, row, time, converged,
                      R_diag, R_nominal, adapt, nis_mean, r_temper, w, factor, seen, rejecting_since, x, P, free,
                      first_param, n_params, max_var, max_log_scale):  # pragma: no cover -- compiled
    """A corrected block's bookkeeping in one call (filters/health.py ``FilterHealth.correct``, the one-call close):
    :func:`book_block`, then where ``adapt`` :func:`adapt_r` with the weight ``w``, then :func:`listen` with the
    channels kept, and :func:`state_fault` of the corrected ``x``, ``P``; the same arithmetic in the same order.
    Returns (kept (m,) bool, the longest unused streak [s], the state's fault code)."""
    nis, keep = book_block(channels, nu, var, vy, vy_scale, innovation_sq, innovation_n, gate_sq, row, time,
                           converged, R_diag, R_nominal)
    if adapt:
        adapt_r(nis, channels, R_diag, R_nominal, nis_mean, r_temper, gate_sq, w, factor)
    n_kept = 0
    for i in range(keep.shape[0]):
        n_kept += keep[i]
    kept = np.empty(n_kept, dtype=np.int64)
    j = 0
    for i in range(keep.shape[0]):
        if keep[i]:
            kept[j] = channels[i]
            j += 1
    longest = listen(seen, kept, rejecting_since, time)
    return keep, longest, state_fault(x, P, free, first_param, n_params, max_var, max_log_scale)


def _masks(n_out: int):
    """The channel masks as the filters pass them: read-only, every one (the configured channels', a pattern's
    shared mask, a sample's own: filters/feeding.py). numba compiles a function once for each array type it is
    given, writable and read-only apart (a compile of :func:`close_block` is 3 s of a first run)."""
    shared = np.ones(n_out, dtype=np.bool_)
    shared.flags.writeable = False
    return (shared,)
