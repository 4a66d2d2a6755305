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
samples up to that one go through the hooks, which set it with numpy's sums.

Compiled at first use and cached on disk (online_id/util/jit.py).
"""

from __future__ import annotations

import numpy as np

from online_id.model.tyres import output, step_input
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
    for k in range(m):
        x, S = step_input(x, S, th, mu, Fz, W[k], shift, V_step[k], dts[k], kn, idx, scale, steer_cols, steer_g)
        if not observe[k]:
            continue
        y, H, C = output(x, S, th, mu, Fz, deltas[k] + shift, speeds[k], kn, idx, scale, steer_cols, steer_g)
        y = y + y_offset
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
