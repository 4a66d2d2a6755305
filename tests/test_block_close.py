"""The array path's compiled pieces (filters/block_close.py, the kinematic balance's running sums) and the
clock's counted quiet steps give the numbers of the numpy and per-sample code they replace, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from online_id.filters import block_close
from online_id.filters.block_update import joseph_update, observed_process_noise
from online_id.filters.kinematics import KinematicBalance
from online_id.stream.gaps import SampleClock

N, M = 14, 5


def _block(rng, m=M, n=N):
    A = rng.standard_normal((n, n))
    P = A @ A.T + np.eye(n)
    F = np.eye(n) + 0.1 * rng.standard_normal((n, n))
    Hbar = rng.standard_normal((m, n))
    C_states = rng.standard_normal((m, 6))
    q = rng.random(n) * 1e-3
    R = rng.random(m) + 0.1
    return P, F, Hbar, C_states, q, R


@pytest.mark.parametrize("seed", range(20))
def test_the_compiled_block_close_is_numpys_arithmetic_bit_for_bit(seed):
    rng = np.random.default_rng(seed)
    P, F, Hbar, C_states, q, R = _block(rng)
    # the covariance's predict: filterpy's dot(F, P).dot(F.T) + Q
    assert np.array_equal(block_close.predict_covariance(F, P, q), np.dot(F, P).dot(F.T) + np.diag(q))
    # the block's covariances (filters/block_update.py's formulas, in numpy)
    He = Hbar.copy()
    He[:, :6] = C_states
    QHe = q[:, None] * He.T
    PHt = P @ Hbar.T
    S_ref = Hbar @ PHt + He @ QHe + np.diag(R)
    C_ref = F @ PHt + QHe
    C, S = block_close.block_covariances(Hbar, C_states, q, P, F, R)
    assert np.array_equal(C, C_ref) and np.array_equal(S, S_ref)
    # the Joseph correction, on every channel and on some
    x, z, zp = rng.standard_normal(N), rng.standard_normal(M), rng.standard_normal(M)
    for keep in (np.ones(M, bool), np.array([True, False, True, True, False])):
        zk, zpk, Ck, Sk = z[keep], zp[keep], C_ref[:, keep], S_ref[np.ix_(keep, keep)]
        K = np.linalg.solve(Sk, Ck.T).T
        KC = K @ Ck.T
        P_ref = P - KC - KC.T + K @ Sk @ K.T
        x_new, P_new = joseph_update(x, P, (z, zp, C_ref, S_ref), keep)
        assert np.array_equal(x_new, x + K @ (zk - zpk))
        assert np.array_equal(P_new, 0.5 * (P_ref + P_ref.T))


def test_the_observed_process_noise_without_a_gap_is_np_means():
    q = np.random.default_rng(0).random(N)
    for observed in ([1, 2, 3, 4, 5], [2, 3, 5], list(range(1, 41))):
        ref = q.copy()
        ref[:6] -= 0.0
        ref *= np.mean(observed) / max(observed[-1], 1)
        assert np.array_equal(observed_process_noise(q, 0.0, None, observed, observed[-1]), ref)


def test_the_kinematic_running_sums_are_the_per_sample_sums():
    rng = np.random.default_rng(1)
    many, one = KinematicBalance(), KinematicBalance()
    for _ in range(200):
        m = int(rng.integers(1, 30))
        dt = (0.01 + 1e-9 * rng.random(m)).tolist()
        V, r, ay = 20 + rng.random(m), rng.standard_normal(m), 3 * rng.standard_normal(m)
        many.add_many(dt, V, r, ay)
        for i in range(m):
            one.add(dt[i], float(V[i]), float(r[i]), float(ay[i]))
    assert many.__dict__ == one.__dict__


def test_the_quiet_steps_are_the_steps_to_the_next_refresh():
    rng = np.random.default_rng(2)
    for _ in range(50):
        clock = SampleClock()
        for _ in range(int(rng.integers(0, 300))):
            n, k = len(clock._steps) + 1, 0
            while not clock._refreshes(n):
                n, k = n + 1, k + 1
            assert clock.quiet_steps() == k
            clock.observe(0.01 * (1 + 0.01 * float(rng.random())))


def test_a_block_with_a_nan_is_corrected_as_numpy_does_it_not_raised():
    """numba's solve raises on a NaN; numpy's carries it on to the filter's health check, which resets the filter
    with its own reason: the compiled close leaves such a block to numpy."""
    rng = np.random.default_rng(3)
    P, F, Hbar, C_states, q, R = _block(rng)
    C, S = block_close.block_covariances(Hbar, C_states, q, P, F, R)
    C[0, 0] = np.nan
    assert not block_close.all_finite(C, S)
    x_new, P_new = joseph_update(np.zeros(N), P, (np.zeros(M), np.zeros(M), C, S), np.ones(M, bool))
    assert not np.isfinite(P_new).all()


def test_a_singular_block_raises_numpys_error():
    rng = np.random.default_rng(4)
    P, F, Hbar, C_states, q, R = _block(rng)
    C = rng.standard_normal((N, M))
    S = np.zeros((M, M))
    with pytest.raises(np.linalg.LinAlgError) as compiled:
        joseph_update(np.zeros(N), P, (np.zeros(M), np.zeros(M), C, S), np.ones(M, bool))
    with pytest.raises(np.linalg.LinAlgError) as plain:
        np.linalg.solve(S, C.T)
    assert str(compiled.value) == str(plain.value)
