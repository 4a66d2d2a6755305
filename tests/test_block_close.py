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


# -- an ordinary block's whole close in one compiled call (filters/ekf.py ``_close_block``) ---------------------


def _closes(est):
    """Count the estimator's blocks closed in one call and those taken step by step."""
    counts = {"one call": 0, "step by step": 0}
    original = est._close_block

    def counted():
        closed = original()
        counts["one call" if closed is not None else "step by step"] += 1
        return closed

    est._close_block = counted
    return counts


@pytest.mark.parametrize("rate, speed_kmh, intersample", [(100.0, 80.0, "cubic"), (1000.0, 80.0, "hold"),
                                                           (100.0, "60:110", "cubic"), (25.0, 80.0, "cubic")])
def test_an_ordinary_block_closed_in_one_call_is_the_step_by_step_close(rate, speed_kmh, intersample):
    """The one-call close and the steps it replaces (catch-up, gate, sums, predict, block covariances, Joseph)
    agree to round-off on the built-in run at a logger's rate and at 1 kHz, at a constant and a changing speed;
    the one call is taken at every block of a clean run."""
    from online_id.estimation import make_estimator
    from online_id.filters.config import FilterConfig
    from online_id.sim.maneuvers import SpeedProfile
    from online_id.sim.simulator import simulate
    from online_id.stream.samples import SampleArrays
    from online_id.vehicle import load_vehicle

    car = load_vehicle("haro2008")
    speed = (SpeedProfile.parse("0:60,10:110,20:60") if isinstance(speed_kmh, str) else speed_kmh / 3.6)
    run = simulate(car, car.truth("track"), duration_s=20.0, rate_hz=rate, seed=3, speed_mps=speed).run
    config = FilterConfig(intersample=intersample)
    fast, slow = make_estimator(car, "ekf", config=config), make_estimator(car, "ekf", config=config)
    counts = _closes(fast)
    slow._close_block = lambda: None  # (the health then takes the steps one by one)
    fast.update_many(SampleArrays.from_run(run))
    slow.update_many(SampleArrays.from_run(run))
    assert counts["one call"] + counts["step by step"] >= fast.events["corrections"]
    # every block at a constant speed; at a changing one the blocks whose speed crosses to a new linearisation
    # point (two runs of samples in the block) are taken step by step
    assert counts["one call"] >= (1.0 if isinstance(speed_kmh, float) else 0.8) * fast.events["corrections"]
    assert fast.events["corrections"] > 0.95 * len(run.time) / fast._correct_every
    assert fast.events == slow.events
    assert np.allclose(fast.x, slow.x, rtol=1e-10, atol=1e-12)
    assert np.allclose(fast.P, slow.P, rtol=1e-9, atol=1e-15 * np.abs(slow.P).max())
    assert np.array_equal(fast.innovations.rows()[:, 0], slow.innovations.rows()[:, 0])
    assert np.allclose(fast.innovations.rows(), slow.innovations.rows(), rtol=1e-8, atol=1e-10, equal_nan=True)


@pytest.mark.parametrize("rate, speed_kmh", [(100.0, 80.0), (100.0, "60:110"), (25.0, 80.0)])
def test_a_whole_block_taken_from_the_arrays_gives_the_pending_groups_numbers(rate, speed_kmh):
    """The array path hands the EKF a run that is a whole block as it is (``_stage_block``, issue 36's cost of a
    100 Hz log: no sample-by-sample appends to the pending group), and its close gives bit for bit what the
    pending group's gives; the trace, read between corrections in batches, is the one read row by row."""
    from online_id.estimation import make_estimator, run_estimator
    from online_id.sim.maneuvers import SpeedProfile
    from online_id.sim.simulator import simulate
    from online_id.stream.samples import SampleArrays, samples_from_run
    from online_id.vehicle import load_vehicle

    car = load_vehicle("haro2008")
    speed = (SpeedProfile.parse("0:60,10:110,20:60") if isinstance(speed_kmh, str) else speed_kmh / 3.6)
    run = simulate(car, car.truth("track"), duration_s=20.0, rate_hz=rate, seed=5, speed_mps=speed).run
    staged, pending = make_estimator(car, "ekf"), make_estimator(car, "ekf")
    taken = {"whole": 0}
    original = staged._close_staged

    def counted():
        closed = original()
        taken["whole"] += closed is not None
        return closed

    staged._close_staged = counted
    pending._stage_block = lambda *args: False  # (every run appended to the pending group, as before)
    a = run_estimator(staged, SampleArrays.from_run(run))
    b = run_estimator(pending, SampleArrays.from_run(run))
    assert taken["whole"] >= 0.8 * staged.events["corrections"] > 0
    assert staged.events == pending.events
    assert np.array_equal(staged.x, pending.x) and np.array_equal(staged.P, pending.P)
    assert np.array_equal(staged.innovations.rows(), pending.innovations.rows(), equal_nan=True)
    assert np.array_equal(a.trace.time, b.trace.time) and np.array_equal(a.trace.values, b.trace.values)
    assert np.array_equal(a.trace.std, b.trace.std)
    # and the trace read in batches is the one read row by row (an iterable of samples: the streaming path)
    c = run_estimator(make_estimator(car, "ekf"), samples_from_run(run))
    assert np.array_equal(a.trace.time, c.trace.time)
    np.testing.assert_allclose(a.trace.values, c.trace.values, rtol=1e-9)


def test_a_block_with_an_outlier_is_closed_step_by_step_and_counted():
    """A spike on a_y fails its sample's gate: the one call does nothing for that block, the steps one by one
    reject the sample and count it, as they did."""
    from online_id.estimation import make_estimator
    from online_id.sim.simulator import simulate
    from online_id.stream.samples import SampleArrays
    from online_id.vehicle import load_vehicle

    car = load_vehicle("haro2008")
    run = simulate(car, car.truth("track"), duration_s=10.0, rate_hz=100.0, seed=4).run
    run.lateral_acceleration[500] += 3.0  # 60 σ of the sensor's noise, inside the plausible range
    est = make_estimator(car, "ekf")
    counts = _closes(est)
    est.update_many(SampleArrays.from_run(run))
    assert est.events["outliers_rejected"] == 1
    assert counts["step by step"] >= 1
    assert counts["one call"] >= counts["step by step"] * 50


@pytest.mark.parametrize("intersample", ["cubic", "hold"])
def test_an_interruption_inside_an_append_leaves_a_filter_that_still_reads_and_goes_on(intersample):
    """Ctrl-C, SIGTERM or SIGHUP raise between any two Python steps: one landing inside the array path's appends
    left the periods of 20 samples in the pending group and not their speeds, and the verdict's first read of the
    filter ended in "cannot reshape array of size 49 into shape (20,7,7)", an internal error instead of the
    interrupted run's JSON (CI, tests/test_signals.py). The half-appended samples are dropped; the filter reads and
    goes on."""
    from online_id.estimation import make_estimator
    from online_id.filters.config import FilterConfig
    from online_id.sim.simulator import simulate
    from online_id.stream.samples import SampleArrays
    from online_id.vehicle import load_vehicle

    car = load_vehicle("haro2008")
    run = simulate(car, car.truth("track"), duration_s=20.0, rate_hz=100.0, seed=6).run
    arrays = SampleArrays.from_run(run)
    est = make_estimator(car, "ekf", config=FilterConfig(intersample=intersample))
    est.update_many(arrays, stop=1003)
    pending = est._pending
    assert len(pending) > 0  # (a group open: the block's samples so far)
    pending.dt.extend([0.01] * 20)  # what an interruption between the appends of 20 samples leaves
    if intersample != "hold":
        pending.slopes.append(np.zeros((20, 3)))
    events = dict(est.events)  # (the verdict's first read)
    assert np.isfinite(est.x).all() and np.isfinite(est.P).all()
    assert len(pending) == len(pending.speed) == len(pending.delta)
    assert events["samples"] == 1003


def test_an_interruption_inside_the_ukf_appends_leaves_a_filter_that_still_reads():
    """The UKF's columns likewise (``_propagate_observe_many`` extends five lists and three row blocks): a
    signal between them must not break the interrupted run's verdict."""
    from online_id.estimation import make_estimator
    from online_id.sim.simulator import simulate
    from online_id.stream.samples import SampleArrays
    from online_id.vehicle import load_vehicle

    car = load_vehicle("haro2008")
    run = simulate(car, car.truth("track"), duration_s=10.0, rate_hz=100.0, seed=7).run
    est = make_estimator(car, "ukf")
    est.update_many(SampleArrays.from_run(run), stop=501)
    est._dt.extend([0.01] * 3)  # the periods in, the rest not yet
    est._speed_held.extend([22.0] * 3)
    events = dict(est.events)
    est._flush()  # (what the verdict's reading and a correction do)
    assert np.isfinite(est.x).all() and np.isfinite(est.P).all()
    assert events["samples"] == 501
