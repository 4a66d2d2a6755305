"""The tyre filters' compiled block loops (online_id/filters/tyre_block.py) against the calls they replace, sample by
sample: the EKF's run (the step with its sensitivities, the outputs, the gate and the sums) and the UKF's sigma pass
(every point's step and outputs, the transform's gate and sums) give the same numbers bit for bit, with the speed
changing at every sample and, for the UKF, axle loads whose longitudinal forces move while the vertical loads stay
(what a per-point cache of the peaks keyed on the vertical loads alone would get wrong)."""

from __future__ import annotations

import numpy as np

from online_id.filters.tyre_block import sigma_tyre_pass, tyre_run
from online_id.model import tyres
from online_id.vehicle import load_vehicle
from online_id.vehicle.parameters import axle_loads
from tests.test_block_close import _closes

CAR = load_vehicle("haro2008")
THETA = CAR.truth("track").to_vector()
KN = tyres.known_array(CAR.known)
M = 40  # samples


def _inputs(seed: int):
    rng = np.random.default_rng(seed)
    dts = np.full(M, 0.01)
    V = 20.0 + np.cumsum(rng.normal(0.0, 0.05, M))  # a new speed every sample
    W = np.zeros((M, 4))
    W[:, 0] = 0.05 * np.sin(np.arange(M) / 4.0)
    W[:, 1] = 0.01
    return rng, dts, V, W


def test_the_ekf_run_is_the_steps_and_outputs_one_by_one():
    rng, dts, V, W = _inputs(1)
    n_aug = 15
    idx = np.full(10, -1, dtype=np.int64)
    idx[:8] = np.arange(6, 14)
    idx[8] = 14
    idx[9] = 14
    scale, none_i, none_g = np.ones(8), np.zeros(0, dtype=np.int64), np.zeros(0)
    mu, Fz = np.array([0.8, 0.8]), np.ascontiguousarray(axle_loads(CAR.known), dtype=float)
    x0, S0 = rng.normal(0.0, 0.01, 6), np.eye(6, n_aug)
    deltas, speeds = W[:, 0] + 0.001, V
    observe = rng.random(M) < 0.8
    mask = np.array([True, True, True, True, False])
    direct = rng.normal(0.0, 0.1, (5, 1))
    y_offset = rng.normal(0.0, 0.01, 5)
    # the measured values: the model's own outputs plus noise, a few far off (gated out)
    x, S, ys = x0.copy(), S0.copy(), []
    for k in range(M):
        x, S = tyres.step_input(x, S, THETA, mu, Fz, W[k], 0.002, V[k], dts[k], KN, idx, scale, none_i, none_g)
        ys.append(tyres.output(x, S, THETA, mu, Fz, deltas[k] + 0.002, speeds[k], KN, idx, scale, none_i, none_g)[0])
    values = np.array(ys) + rng.normal(0.0, 1e-3, (M, 5))
    values[::7, 3] += 50.0
    thr = np.full(5, 1e-2)

    # the reference: the calls one by one, then the hooks' numpy
    x, S = x0.copy(), S0.copy()
    sums = [np.zeros(5), np.zeros(5), np.zeros((5, n_aug)), np.zeros(5)]
    rejected_ref, accepted_ref, C_ref = np.zeros(5, dtype=np.int64), [], None
    for k in range(M):
        x, S = tyres.step_input(x, S, THETA, mu, Fz, W[k], 0.002, V[k], dts[k], KN, idx, scale, none_i, none_g)
        if not observe[k]:
            continue
        y, H, C = tyres.output(x, S, THETA, mu, Fz, deltas[k] + 0.002, speeds[k], KN, idx, scale, none_i, none_g)
        y = y + y_offset
        H[:, 14:] += direct
        r = values[k] - y
        accept = mask & (r * r <= thr)
        rejected_ref += mask & ~accept
        if not accept.any():
            continue
        accepted_ref.append(k)
        w = accept.astype(float)
        sums[0] += w * y
        sums[1] += w * values[k]
        sums[2] += w[:, None] * H
        sums[3] += w
        C_ref = C

    got = [np.zeros(5), np.zeros(5), np.zeros((5, n_aug)), np.zeros(5)]
    C_last, accepted, rejected = np.empty((5, 6)), np.empty(M, dtype=np.int64), np.zeros(5, dtype=np.int64)
    xg, Sg, n_acc = tyre_run(x0.copy(), S0.copy(), THETA, mu, Fz, W, 0.002, V, dts, KN, idx, scale, none_i, none_g,
                             values, mask, deltas, speeds, observe, y_offset, direct, thr, *got, C_last, accepted,
                             rejected)
    np.testing.assert_array_equal(xg, x)
    np.testing.assert_array_equal(Sg, S)
    for a, b in zip(got, sums):
        np.testing.assert_array_equal(a, b)
    assert accepted[:n_acc].tolist() == accepted_ref and 0 < n_acc <= observe.sum()
    np.testing.assert_array_equal(rejected, rejected_ref)
    assert rejected[3] > 0  # (the a_y readings 50 m/s² off: gated out, the other channels kept)
    np.testing.assert_array_equal(C_last, C_ref)


def test_the_ukf_sigma_pass_is_the_points_stepped_one_sample_at_a_time():
    rng, dts, V, W = _inputs(2)
    P = 7
    thetas = THETA * np.exp(rng.normal(0.0, 0.2, (P, 8)))
    mus = np.full((P, 2), 0.8) * np.exp(rng.normal(0.0, 0.1, (P, 2)))
    shifts = rng.normal(0.0, 0.002, P)
    Fz = np.asarray(axle_loads(CAR.known), dtype=float)
    # combined slip's loads: [Fz1, Fz2, Fx1, Fx2], the longitudinal forces moving while the vertical loads stay
    loads = np.column_stack([np.broadcast_to(Fz, (M, 2)), np.linspace(-2000.0, 1500.0, M), np.zeros(M)])
    loads_out = loads[::-1].copy()
    X0 = rng.normal(0.0, 0.01, (P, 6))
    observed = rng.random(M) < 0.8
    masks = rng.random((M, 5)) < 0.9
    deltas, speeds = W[:, 0], V + 0.01
    y_offset = rng.normal(0.0, 0.01, (P, 5))
    Wm = np.full(P, 1.0 / P)
    Wc = Wm.copy()
    R_now, gate2 = np.full(5, 1e-4), 9.0
    values = rng.normal(0.0, 0.05, (M, 5))

    X = X0.copy()
    ref_y, ref_z, ref_n, ref_rej = np.zeros((P, 5)), np.zeros(5), np.zeros(5), np.zeros(5, dtype=np.int64)
    for k in range(M):
        X = tyres.step_points_input(X, thetas, mus, loads[k], W[k], shifts, V[k], dts[k], KN)
        if not observed[k]:
            continue
        Y = tyres.output_points(X, thetas, mus, loads_out[k], np.ascontiguousarray(deltas[k] + shifts), speeds[k], KN)
        Y = Y + y_offset
        yp = Wm @ Y
        var = Wc @ (Y - yp) ** 2 + R_now
        accept = masks[k] & ((values[k] - yp) ** 2 <= gate2 * var)
        ref_rej += masks[k] & ~accept
        w = accept.astype(float)
        ref_y += Y * w
        ref_z += np.where(accept, values[k], 0.0)
        ref_n += w

    sum_y, sum_z, n, rejected = np.zeros((P, 5)), np.zeros(5), np.zeros(5), np.zeros(5, dtype=np.int64)
    Xg = sigma_tyre_pass(X0.copy(), thetas, mus, loads, loads_out, W, shifts, V, dts, KN, observed, values, masks,
                         deltas, speeds, y_offset, Wm, Wc, R_now, gate2, sum_y, sum_z, n, rejected)
    np.testing.assert_array_equal(Xg, X)
    np.testing.assert_array_equal(sum_y, ref_y)
    np.testing.assert_array_equal(sum_z, ref_z)
    np.testing.assert_array_equal(n, ref_n)
    np.testing.assert_array_equal(rejected, ref_rej)
    assert 0 < ref_n.sum() < observed.sum() * 5


def test_the_tyre_ekfs_block_close_in_one_call_is_the_hooks_close():
    """``TyreEKFEstimator._close_block`` (``tyre_close``: flush, block innovation, block gate, Joseph covariance; then
    the health's one-call bookkeeping) against the hooks it replaces (the health's steps, ``_close_block`` off), on a
    0.85 g run at 100 Hz with the speed changing: the one call taken at nearly every block, and the mean, covariance,
    events and innovation log the same bit for bit (measured; the two share the BLAS's products, as
    tests/test_block_close.py checks for the linear EKF's close)."""
    from online_id.effects import parse_effect, parse_effect_to_estimate
    from online_id.estimation import make_estimator
    from online_id.sim.maneuvers import SpeedProfile
    from online_id.sim.simulator import simulate
    from online_id.stream.samples import SampleArrays

    run = simulate(CAR, CAR.truth("track"), duration_s=20.0, rate_hz=100.0, seed=4, amplitude_rad=np.deg2rad(50),
                   speed_mps=SpeedProfile.parse("0:60,10:100,20:60"), effects=[parse_effect("tire_saturation=0.8")]).run
    tyre = [parse_effect_to_estimate("tire_saturation")]
    fast, slow = make_estimator(CAR, "ekf", effects=tyre), make_estimator(CAR, "ekf", effects=tyre)
    calls = _closes(fast)
    slow._close_block = lambda: None  # (the health then takes the hooks' steps)
    fast.update_many(SampleArrays.from_run(run))
    slow.update_many(SampleArrays.from_run(run))
    assert np.max(np.abs(run.lateral_acceleration)) > 0.8 * 9.81
    assert calls["one call"] >= 0.9 * fast.events["corrections"] > 0
    assert fast.events == slow.events
    np.testing.assert_array_equal(fast.x, slow.x)
    np.testing.assert_array_equal(fast.P, slow.P)
    np.testing.assert_array_equal(fast.innovations.rows(), slow.innovations.rows())
