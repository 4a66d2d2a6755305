"""Group arithmetic (filters/groups.py) and the block's running sums (filters/block_sums.py) against plain loops."""

from __future__ import annotations

import numpy as np
import pytest

from online_id.filters.block_sums import BlockSums
from online_id.filters.groups import (
    chain_jacobians,
    constant_transition_table,
    propagate_mean,
    recurse_group,
    transition_table,
)
from online_id.filters.local_model import LinearOutputs


def _loop(Ad, b, x0, F0, J):
    """x_j = Ad_j x_j-1 + b_j and F_j = Ad_j F_j-1 + [0 | J_j], one sample at a time."""
    n, P = x0.size, J.shape[2]
    X, F = [x0], [F0]
    for j in range(len(Ad)):
        X.append(Ad[j] @ X[-1] + b[j])
        Fj = Ad[j] @ F[-1]
        Fj[:, -P:] += J[j]
        F.append(Fj)
    assert F0.shape[1] == n + P
    return np.array(X), np.array(F)


@pytest.mark.parametrize("K", [1, 4])
def test_the_compiled_recursion_equals_the_sample_loop(K):
    """recurse_group (the EKF's one-period groups): the parameters' columns from each run's table, the extra
    states' from Γ_0 gᵀ, two runs at two linearisation points; the steps' inputs the hold's δ (K = 1) or an input
    polynomial's value and derivatives (K = 4: Γ w, and [x; w] through tables of 6 + 4 rows)."""
    rng = np.random.default_rng(1)
    n, P, n_extra, m = 6, 8, 2, 13
    Ad = np.eye(n) + 0.1 * rng.normal(size=(m, n, n))
    Gamma, w, x0 = rng.normal(size=(m, n, K)), rng.normal(size=(m, K)), rng.normal(size=n)
    columns = rng.normal(size=(2, n + K, P * n))
    run_of = np.array([0] * 5 + [1] * (m - 5), dtype=np.int64)
    g = rng.normal(size=n_extra)
    F0 = rng.normal(size=(n, n + P + n_extra))
    X, F = np.empty((m + 1, n)), np.empty((m + 1, n, n + P + n_extra))
    X[0], F[0] = x0, F0
    recurse_group(Ad, Gamma, columns, run_of, g, w, X, F)
    J = np.empty((m, n, P + n_extra))
    b = np.einsum("mak,mk->ma", Gamma, w)
    X_ref, _ = _loop(Ad, b, x0, F0, np.zeros((m, n, P + n_extra)))
    for j in range(m):
        z = np.concatenate([X_ref[j], w[j]])
        J[j, :, :P] = (z @ columns[run_of[j]]).reshape(P, n).T
        J[j, :, P:] = np.outer(Gamma[j, :, 0], g)
    X_ref, F_ref = _loop(Ad, b, x0, F0, J)
    np.testing.assert_allclose(X, X_ref, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(F, F_ref, rtol=1e-12, atol=1e-12)


def test_a_group_of_varying_steps_equals_the_sample_loop():
    rng = np.random.default_rng(0)
    for m in (1, 2, 3, 7, 16, 20):
        n, P = 6, 11  # 11 constant states: the 8 parameters plus, say, 3 sensor offsets
        Ad = np.eye(n) + 0.1 * rng.normal(size=(m, n, n))
        b, x0 = rng.normal(size=(m, n)), rng.normal(size=n)
        F0, J = rng.normal(size=(n, n + P)), rng.normal(size=(m, n, P))
        A, T = transition_table(Ad)
        X_ref, F_ref = _loop(Ad, b, x0, F0, J)
        np.testing.assert_allclose(propagate_mean(A, T, x0, b), X_ref, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(chain_jacobians(A, T, F0, J), F_ref, rtol=1e-12, atol=1e-12)
        A1, T1 = constant_transition_table(Ad[0], m)
        A2, T2 = transition_table(np.broadcast_to(Ad[0], (m, n, n)).copy())
        np.testing.assert_allclose(A1, A2, rtol=1e-12, atol=1e-13)
        np.testing.assert_allclose(T1, T2, rtol=1e-12, atol=1e-13)
        assert np.all(T[:n, n:] == 0)  # nothing from later samples reaches earlier ones


def _outputs(rng, P=8):
    return LinearOutputs(rng.normal(size=(4, 6)), rng.normal(size=4), rng.normal(size=(4 * P, 6)),
                         rng.normal(size=(4, P)))


def test_block_sums_fold_to_the_per_sample_sums():
    """Summing F_x, x, δ and folding once equals summing each sample's ŷ and H, across mask and output
    changes and with partly accepted samples."""
    rng = np.random.default_rng(1)
    N = 14
    sums, ref = BlockSums(4, N, 6), BlockSums(4, N, 6)
    outs = [_outputs(rng), _outputs(rng)]
    masks = [np.array([True, True, True, True]), np.array([True, False, False, True])]
    for k in range(30):
        out, mask = outs[k // 15], masks[(k // 5) % 2]
        z, x, F, d = rng.normal(size=4), rng.normal(size=6), rng.normal(size=(6, N)), rng.normal()
        if k % 7 == 3:  # one channel rejected: sample by sample
            accept = mask.copy()
            accept[0] = False
            y, H = out.predict(x[None], np.array([d]))[0], out.sensitivity(F, x, d)
            sums.add_channels(accept, z, y, H)
            ref.add_channels(accept, z, y, H)
            continue
        sums.add_accepted(mask, out, 1, np.where(mask, z, 0.0), F, x, d)
        ref.add_channels(mask, z, out.predict(x[None], np.array([d]))[0], out.sensitivity(F, x, d))
    got, want = sums.means(), ref.means()
    for a, b in zip(got, want):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12)
    assert BlockSums(4, N, 6).means() is None
