"""The EKF with saturating tyres over a run of samples in one compiled call (issue 40 item 2).

:class:`~online_id.filters.tyre_filters.TyreEKFEstimator` works a sample as two compiled calls (the model's step
with its sensitivities, :func:`online_id.model.tyres.step_input`, and its outputs, :func:`~online_id.model.tyres.
output`) and a few dozen numpy calls around them (the output offsets of the extra states, the outlier gate, the
block's sums): at 1 kHz the calls cost three times the arithmetic (38 µs a sample against 13). The array path
(:meth:`~online_id.filters.feeding.SampleFeeding.update_many`) hands the filter runs of ordinary samples up to
the one that closes a block; :func:`tyre_run` works such a run as the per-sample hooks do, the same calls in the
same order, so the numbers are theirs (``tests/test_array_path.py``): each step, then where the sample is
observed its outputs, the extra states' offsets and direct output terms, the gate and the accepted channels'
sums. The gate's threshold is the block's (gate_sigma² (diag(H P Hᵀ) + R) at its first observed sample): the
samples up to that one go through the hooks, which set it with numpy's sums. The step's and the output's work are
those of ``step_input`` and ``output`` (``_step_into``, ``_output_into``), the stages' and the outputs' buffers
made once for the run (E⁻¹ and the tyre terms still a few small arrays a sample).

Compiled at first use and cached on disk (online_id/util/jit.py).
"""

from __future__ import annotations

import numpy as np

from online_id.filters.block_close import all_finite, block_covariances, joseph_covariance, predict_covariance
from online_id.model.lateral import D1, D2, N_STATES
from online_id.model.tyres import (
    _output_into,
    _peaks,
    _step_into,
    advance_points,
    floor_points,
    floored,
    output_points,
    points_parts,
    step_parts,
)
from online_id.util.jit import cached_njit


@cached_njit(fastmath=False)
def tyre_run(x, S, th, mu, Fz, W, shift, V_step, dts, kn, idx, scale, steer_cols, steer_g, values, mask, deltas,
             speeds, observe, y_offset, direct, thr, sum_y, sum_z, sum_H, n, C_last, accepted,
             rejected):  # pragma: no cover -- compiled
    """Samples k = 0..m-1 of a run: the step into each (``dts`` (m,) [s], inputs ``W`` (m, 4) plus ``shift``, held
    speeds ``V_step`` (m,)) from the model states ``x`` (6,) and their sensitivity ``S`` (6, n_aug), then where
    ``observe[k]`` its outputs at δ ``deltas[k]`` + ``shift`` and speed ``speeds[k]``, plus ``y_offset`` (5,), with
    ``direct`` (5, n_extra) added to the extra states' columns of H, gated against ``values[k]`` (5,) on the
    channels of ``mask`` (5,).

    ``thr`` (5,) is the gate's threshold (the block's, set by the hooks at its first observed sample). In place: the
    block's sums ``sum_y``, ``sum_z`` (5,), ``sum_H`` (5, n_aug), ``n`` (5,), ``C_last`` (5, 6) the last accepted
    sample's ∂y/∂x, ``accepted`` (m,) the samples with an accepted channel (their indices first), ``rejected``
    (5,) the gated-out channels counted. Returns (x, S, the number of samples with an accepted channel)."""
    m = dts.shape[0]
    n_extra = direct.shape[1]
    first_extra = S.shape[1] - n_extra
    n_accepted = 0
    # step_input's work with its buffers made once for the run (not twice a sample): the same arithmetic
    x = x.copy()
    S = S.copy()
    n_aug = S.shape[1]
    th_f = floored(th)
    D = np.array([th_f[D1], th_f[D2]])
    peak = np.empty(4)
    dpeak = np.empty(4)
    _peaks(mu, Fz, peak, dpeak)
    F = np.empty((4, N_STATES))
    K = np.empty((4, N_STATES, n_aug))
    xs = np.empty(N_STATES)
    Ss = np.empty((N_STATES, n_aug))
    y = np.empty(5)  # (output's buffers)
    H = np.empty((5, n_aug))
    C = np.empty((5, N_STATES))
    f_out = np.empty(N_STATES)
    K_out = np.empty((N_STATES, n_aug))
    for k in range(m):
        _step_into(x, S, F, K, xs, Ss, th_f, D, peak, mu, dpeak, W[k], shift, V_step[k], dts[k], kn, idx, scale,
                   steer_cols, steer_g)
        if not observe[k]:
            continue
        _output_into(y, H, C, f_out, K_out, x, S, th_f, mu, deltas[k] + shift, speeds[k], kn, idx, scale, steer_cols,
                     steer_g, D, peak, dpeak)
        for i in range(5):
            y[i] += y_offset[i]
        if n_extra:
            for i in range(5):
                for j in range(n_extra):
                    H[i, first_extra + j] += direct[i, j]
        any_accepted = False
        for i in range(5):
            r = values[k, i] - y[i]
            if mask[i]:
                if r * r <= thr[i]:
                    any_accepted = True
                else:
                    rejected[i] += 1
        if not any_accepted:
            continue
        accepted[n_accepted] = k
        n_accepted += 1
        for i in range(5):
            r = values[k, i] - y[i]
            w = 1.0 if mask[i] and r * r <= thr[i] else 0.0
            sum_y[i] += w * y[i]
            sum_z[i] += w * values[k, i]
            for j in range(H.shape[1]):
                sum_H[i, j] += w * H[i, j]
            n[i] += w
        C_last[:, :] = C
    return x, S, n_accepted


@cached_njit(fastmath=False)
def tyre_close(x_states_S, P, q, share, sum_y, sum_z, sum_H, n, C_last, R_now, gate_sq):  # pragma: no cover
    """A tyre EKF block's close up to its gain, as the hooks take it (``_flush``, ``_block_innovation``, the
    block's gate of ``FilterHealth.correct``, ``joseph_update``'s compiled part), for a block with no long gap:
    ``x_states_S`` (6, n) the model states' sensitivity to the block-start state (F's first rows), ``P`` (n, n) at
    the block start, ``q`` (n,) the block's process noise, ``share`` the observations' share of it. Returns
    (status, channels, z, ẑ, P predicted, K, P corrected, S): status 0 where every channel passes the block's gate
    and the numbers are finite (then K (z − ẑ) is the caller's, in numpy's order), else 1 (nothing to keep: the
    hooks then take the block)."""
    size = P.shape[0]
    F = np.eye(size)
    F[:x_states_S.shape[0], :] = x_states_S
    P_pred = predict_covariance(F, P, q)
    P_pred = 0.5 * (P_pred + P_pred.T)
    m = 0
    for i in range(n.shape[0]):
        if n[i] > 0:
            m += 1
    channels = np.empty(m, dtype=np.int64)
    j = 0
    for i in range(n.shape[0]):
        if n[i] > 0:
            channels[j] = i
            j += 1
    z = np.empty(m)
    zp = np.empty(m)
    Hbar = np.empty((m, size))
    C_states = np.empty((m, C_last.shape[1]))
    R_over_n = np.empty(m)
    for a in range(m):
        c = channels[a]
        z[a] = sum_z[c] / n[c]
        zp[a] = sum_y[c] / n[c]
        for b in range(size):
            Hbar[a, b] = sum_H[c, b] / n[c]
        C_states[a, :] = C_last[c, :]
        R_over_n[a] = R_now[c] / n[c]
    C, S = block_covariances(Hbar, C_states, q * share, P, F, R_over_n)
    empty = np.empty((0, 0))
    for a in range(m):
        if not (z[a] - zp[a]) ** 2 / S[a, a] <= gate_sq:
            return 1, channels, z, zp, P_pred, empty, empty, S
    if not all_finite(C, S):
        return 1, channels, z, zp, P_pred, empty, empty, S
    K, P_new = joseph_covariance(P_pred, C, S)
    return 0, channels, z, zp, P_pred, K, P_new, S


@cached_njit(fastmath=False)
def sigma_tyre_pass(X, thetas, mus, Fz_step, Fz_out, W, shifts, V_step, dts, kn, observed, values, masks, deltas,
                    speeds, y_offset, Wm, Wc, R_now, gate2, sum_y, sum_z, n, rejected):  # pragma: no cover
    """The UKF with saturating tyres over a block's buffered samples (its ``_propagate_sigmas`` loop, the same
    calls in the same order): every sigma point X (S, 6) stepped through each sample (``dts`` (m,), inputs ``W``
    (m, 4) plus each point's steering shift ``shifts`` (S,), held speeds ``V_step``, the loads of the step and of the
    output ``Fz_step``, ``Fz_out`` (m, 2)), and where ``observed[k]`` the points' outputs (at δ ``deltas[k]`` + shift,
    speed ``speeds[k]``, plus ``y_offset`` (S, 5)) gated on the channels ``masks[k]`` against the transform's
    variance (weights ``Wm``, ``Wc``, noise ``R_now``, gate² ``gate2``) and summed into ``sum_y`` (S, 5), ``sum_z``,
    ``n`` (5,) in place; ``rejected`` (5,) counts the gated-out channels. Returns the stepped points.

    :func:`~online_id.model.tyres.step_points_input`'s arithmetic, each point's sub-step count, E⁻¹ and E⁻¹A (functions
    of its θ, the step's period and speed) and its peaks (of μ and the loads) kept while those repeat (a steady
    speed, static loads): the same numbers."""
    parts = points_parts(X.shape[0])
    floor_points(thetas, parts[0])
    X = X.copy()
    last_dt, last_V = np.nan, np.nan
    last_loads = np.full(Fz_step.shape[1], np.nan)  # (the axle loads, and their longitudinal forces where given)
    for k in range(dts.shape[0]):
        dt, V = dts[k], V_step[k]
        new_step = dt != last_dt or V != last_V
        new_loads = False
        for j in range(Fz_step.shape[1]):
            if Fz_step[k, j] != last_loads[j]:
                new_loads = True
            last_loads[j] = Fz_step[k, j]
        last_dt, last_V = dt, V
        step_parts(parts, mus, Fz_step[k], V, dt, kn, new_step, new_loads)
        advance_points(X, parts, W[k], shifts, V, dt, kn)
        if not observed[k]:
            continue
        Y = output_points(X, thetas, mus, Fz_out[k], deltas[k] + shifts, speeds[k], kn)
        Y = Y + y_offset
        yp = Wm @ Y
        var = Wc @ (Y - yp) ** 2 + R_now
        for i in range(5):
            accept = masks[k, i] and (values[k, i] - yp[i]) ** 2 <= gate2 * var[i]
            if masks[k, i] and not accept:
                rejected[i] += 1
            w = 1.0 if accept else 0.0
            for s in range(Y.shape[0]):
                sum_y[s, i] += Y[s, i] * w
            sum_z[i] += values[k, i] if accept else 0.0
            n[i] += w
    return X
