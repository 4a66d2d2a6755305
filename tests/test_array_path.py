"""The array path (issue 26): a whole run fed as arrays (``OnlineEstimator.update_many(SampleArrays)``,
what ``run_estimator`` and the offline workflows use) gives the numbers of the streaming ``update(sample)``
one sample at a time: the estimate, its σ, the events, the outliers, the trace, for the EKF and the UKF, with
saturating tyres, sensor offsets and a delay, and on a run that trips the guards (a spike, NaNs, a gap, lost
samples, a stop, a repeated time stamp, a channel that comes and goes).
"""

from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np
import pytest

from online_id.effects import parse_effect_to_estimate
from online_id.estimation import make_estimator, run_estimator
from online_id.filters import FilterConfig
from online_id.filters.sigma_block import sigma_expm_steps, sigma_pass, sigma_steps, step_rows
from online_id.model.discretise import continuous_speed_derivatives, spectral_form
from online_id.sim.simulator import simulate
from online_id.stream.samples import Sample, SampleArrays, samples_from_run
from online_id.vehicle import load_vehicle

CAR = load_vehicle("haro2008")
TRUTH = CAR.truth("track")
#: Relative agreement asked of the two paths (they run the same arithmetic: measured, they agree exactly).
RTOL = 1e-9
#: Every comparison runs with the hold's input between samples and with the cubic's (model/intersample.py:
#: the streaming path works each sample when the next has come, the array path has them all).
KINDS = ("hold", "cubic")


def _damaged_run(duration_s=6.0, seed=3):
    """The chirp with what the guards are for: a spike, NaNs, a repeated time stamp, lost samples (bridged),
    a long gap (a restart), a stop (low speed)."""
    run = simulate(CAR, TRUTH, duration_s=duration_s, seed=seed).run
    t, V = run.time.copy(), run.speed.copy()
    r, ay = run.yaw_rate.copy(), run.lateral_acceleration.copy()
    n = len(t)
    at = [int(n * f) for f in (0.25, 0.35, 0.43, 0.5, 0.58, 0.67)]
    r[at[0]] += 2.0  # a spike the gate rejects
    ay[at[1]:at[1] + 3] = np.nan  # missing values
    t[at[2]] = t[at[2] - 1]  # a repeated time stamp (the sample is invalid)
    V[at[5]:at[5] + 200] = 0.5  # a stop: below min_speed, the states restart
    keep = np.ones(n, dtype=bool)
    keep[at[3]:at[3] + 4] = False  # lost samples, bridged
    keep[at[4]:at[4] + 200] = False  # a gap longer than max_gap_s: a restart
    return replace(run, time=t[keep], speed=V[keep], yaw_rate=r[keep], lateral_acceleration=ay[keep],
                   steering_wheel_angle=run.steering_wheel_angle[keep], roll_angle=run.roll_angle[keep],
                   roll_rate=run.roll_rate[keep])


def _both(filt, run, kind="hold", **kw):
    """(per-sample result, array result) of the same run, with the intersample model ``kind`` (unless a
    ``config`` is given)."""
    kw.setdefault("config", FilterConfig(intersample=kind))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        one = run_estimator(make_estimator(CAR, filt, **kw), list(samples_from_run(run)))
        many = run_estimator(make_estimator(CAR, filt, **kw), SampleArrays.from_run(run))
    return one, many


def _assert_same(one, many):
    np.testing.assert_allclose(many.parameters.to_vector(), one.parameters.to_vector(), rtol=RTOL, atol=0)
    np.testing.assert_allclose(many.std, one.std, rtol=RTOL, atol=0)
    np.testing.assert_allclose(many.covariance, one.covariance, rtol=RTOL, atol=1e-300)
    assert many.events == one.events
    assert many.gated == one.gated
    assert many.samples == one.samples
    np.testing.assert_array_equal(many.trace.time, one.trace.time)
    np.testing.assert_allclose(many.trace.values, one.trace.values, rtol=RTOL, atol=0)
    np.testing.assert_allclose(many.trace.std, one.trace.std, rtol=RTOL, atol=0)
    assert many.extra_states.keys() == one.extra_states.keys()
    assert many.innovation_rms == pytest.approx(one.innovation_rms, rel=RTOL)


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("filt", ["ekf", "ukf"])
def test_the_array_path_gives_the_per_sample_numbers(filt, kind):
    one, many = _both(filt, simulate(CAR, TRUTH, duration_s=6.0, seed=1).run, kind)
    _assert_same(one, many)
    assert one.events["corrections"] > 200


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("filt", ["ekf", "ukf"])
def test_the_array_path_keeps_every_guard(filt, kind):
    """Every guard fires on the damaged run, and the array path counts and corrects as the samples do."""
    one, many = _both(filt, _damaged_run(), kind)
    _assert_same(one, many)
    for event in ("outliers_rejected", "missing_values", "invalid_samples", "missing_samples", "gaps",
                  "frozen_low_speed"):
        assert one.events.get(event, 0) > 0, event


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("filt", ["ekf", "ukf"])
def test_the_array_path_with_saturating_tyres(filt, kind):
    tyre = [parse_effect_to_estimate("tire_saturation")]
    one, many = _both(filt, _damaged_run(2.5), kind, effects=tyre)
    _assert_same(one, many)
    assert one.extra_states


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("filt", ["ekf", "ukf"])
def test_the_array_path_with_offsets_and_a_delay(filt, kind):
    one, many = _both(filt, _damaged_run(3.0), kind, offsets=True)
    _assert_same(one, many)
    delay = [parse_effect_to_estimate("sensor_delay:yaw_rate")]
    one, many = _both(filt, simulate(CAR, TRUTH, duration_s=3.0, seed=2).run, kind, effects=delay)
    _assert_same(one, many)


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("run", [simulate(CAR, TRUTH, duration_s=6.0, seed=1).run, _damaged_run()],
                         ids=["clean", "damaged"])
def test_the_array_path_keeps_the_kinematic_balance_and_the_clock(run, kind):
    """Their running sums are taken a run at a time on the array path (the a_y − V·r balance, the period's
    refresh every 64 steps inside a run): the same numbers, bit for bit, as sample by sample."""
    ests = []
    for feed in (list(samples_from_run(run)), SampleArrays.from_run(run)):
        est = make_estimator(CAR, "ekf", config=FilterConfig(intersample=kind))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            est.update_many(feed)
        ests.append(est)
    one, many = ests
    assert many.kinematics.__dict__ == one.kinematics.__dict__
    assert many.kinematics.duration > 0.9 * (run.time[-1] - run.time[0]) - 0.5
    assert many._clock.__dict__ == one._clock.__dict__
    assert many._clock.period == pytest.approx(1e-3)


@pytest.mark.parametrize("kind", KINDS)
def test_samples_with_a_channel_that_comes_and_goes(kind):
    """Samples whose roll channels are absent (None) in part of the run: the array path's masks are the
    per-sample path's."""
    run = simulate(CAR, TRUTH, duration_s=3.0, seed=4).run
    samples = list(samples_from_run(run))
    samples[1000:1400] = [Sample(s.time, s.steering_wheel_angle, s.speed, yaw_rate=s.yaw_rate,
                                 lateral_acceleration=s.lateral_acceleration) for s in samples[1000:1400]]
    for filt in ("ekf", "ukf"):
        config = FilterConfig(intersample=kind)
        one = run_estimator(make_estimator(CAR, filt, config=config), samples)
        many = run_estimator(make_estimator(CAR, filt, config=config), SampleArrays.from_samples(samples))
        _assert_same(one, many)


def test_sample_arrays_round_trip():
    run = simulate(CAR, TRUTH, duration_s=0.05, seed=0).run
    arrays = SampleArrays.from_run(run, ("yaw_rate", "roll_rate"))
    assert list(arrays) == list(samples_from_run(run, ("yaw_rate", "roll_rate")))
    again = SampleArrays.from_samples([arrays.sample(k) for k in range(len(arrays))])
    for name in ("time", "steering_wheel_angle", "speed", "values", "absent"):
        np.testing.assert_array_equal(getattr(again, name), getattr(arrays, name))


def test_run_estimator_with_a_per_sample_callback_takes_the_samples_one_by_one():
    """``on_sample`` (a live table) wants each sample: given arrays, run_estimator feeds their rows one by one."""
    run = simulate(CAR, TRUTH, duration_s=0.5, seed=0).run
    seen = []
    res = run_estimator(make_estimator(CAR, "ekf"), SampleArrays.from_run(run), on_sample=lambda e, s: seen.append(s))
    assert seen == list(samples_from_run(run)) and res.samples == len(run)


def test_sigma_steps_are_the_spectral_forms_transitions():
    """The UKF's compiled steps (filters/sigma_block.py) against SpectralForm.transitions (numpy), at varying
    periods and speeds, for a batch of parameter sets."""
    rng = np.random.default_rng(0)
    thetas = TRUTH.to_vector() * np.exp(0.3 * rng.standard_normal((5, 8)))
    V_ref = 20.0
    Ac, Bc, dAc, dBc = continuous_speed_derivatives(thetas, V_ref, CAR.known)
    form = spectral_form(Ac, Bc, dAc[:, None], dBc[:, None])
    dt = np.array([1e-3, 1e-3, 2e-3, 1e-3, 5e-4])
    c = np.array([[0.0], [0.0], [0.3], [-0.2], [-0.2]])
    Ad, Bd = np.empty((5, 5, 6, 6)), np.empty((5, 5, 6, 1))
    sigma_steps(form.eigenvalues, form.vectors, form.inverse, form.directions, dt, c, 0.0, Ad, Bd)
    Phi = form.transitions(dt, c)
    np.testing.assert_allclose(Ad, Phi[..., :6, :6], rtol=0, atol=1e-13)
    np.testing.assert_allclose(Bd[..., 0], Phi[..., :6, 6], rtol=0, atol=1e-13)


def test_sigma_expm_steps_are_the_spectral_forms_transitions():
    """The UKF's compiled Padé steps (filters/sigma_block.py) against SpectralForm.transitions, at varying
    periods and speeds (and none: no derivative formed), for a batch of parameter sets."""
    rng = np.random.default_rng(0)
    thetas = TRUTH.to_vector() * np.exp(0.3 * rng.standard_normal((5, 8)))
    Ac, Bc, dAc, dBc = continuous_speed_derivatives(thetas, 20.0, CAR.known)
    form = spectral_form(Ac, Bc, dAc[:, None], dBc[:, None])
    G, dG = np.zeros((5, 7, 7)), np.zeros((5, 1, 7, 7))
    G[:, :6, :6], G[:, :6, 6], dG[:, 0, :6, :6], dG[:, 0, :6, 6] = Ac, Bc, dAc, dBc
    dt = np.array([1e-3, 1e-3, 2e-3, 1e-3, 5e-4, 5e-4])
    for c in (np.array([[0.0], [0.0], [0.3], [-0.2], [-0.2], [0.1]]), np.zeros((6, 1))):
        Ad, Bd = np.empty((5, 6, 6, 6)), np.empty((5, 6, 6, 1))
        sigma_expm_steps(G, dG, dt, c, 0.0, Ad, Bd)
        Phi = form.transitions(dt, c)
        np.testing.assert_allclose(Ad, Phi[..., :6, :6], rtol=0, atol=1e-13)
        np.testing.assert_allclose(Bd[..., 0], Phi[..., :6, 6], rtol=0, atol=1e-13)


def test_step_rows_share_a_step_between_samples_of_one_period_and_speed():
    """A sample takes the step of the one before when its period is that one's within the tolerance and its
    speed coefficient the same; the compiled pass through the shared steps is the pass through each sample's."""
    dt = np.array([1e-3, 1e-3 * (1 + 1e-12), 1e-3, 2e-3, 2e-3, 2e-3])
    c = np.array([[0.0], [0.0], [0.1], [0.1], [0.1], [0.0]])
    rows = step_rows(dt, c, 1e-9)
    np.testing.assert_array_equal(rows, [0, 0, 1, 2, 2, 3])
    np.testing.assert_array_equal(step_rows(dt, c, 0.0), [0, 1, 2, 3, 3, 4])
    rng = np.random.default_rng(2)
    S, m = 3, len(dt)
    Ad, Bd = np.eye(6) + 0.01 * rng.standard_normal((S, 4, 6, 6)), 0.01 * rng.standard_normal((S, 4, 6, 1))
    z = np.zeros
    X0, C = rng.standard_normal((S, 6)), rng.standard_normal((S, 4, 6))
    delta = np.column_stack([rng.standard_normal(m), z((m, 3))])  # the hold's inputs w
    results = []
    for A, B, r in ((Ad, Bd, rows), (Ad[:, rows].copy(), Bd[:, rows].copy(), np.arange(m))):
        X, sums = X0.copy(), (z((S, 4)), z(4), z(4), z(4, dtype=np.int64))
        sigma_pass(A, B, r, X, delta, z(m), np.ones(m, dtype=bool), z((m, 4)), np.ones((m, 4), dtype=bool), C,
                   z((S, 4)), z(S), z((S, 4)), z((S, 4)), z((S, 4, 6)), z((S, 4)), np.full(S, 1 / S),
                   np.full(S, 1 / S), np.ones(4), 25.0, *sums)
        results.append((X, sums[0]))
    np.testing.assert_array_equal(results[0][0], results[1][0])
    np.testing.assert_array_equal(results[0][1], results[1][1])


def test_sigma_pass_gates_and_sums_as_numpy_does():
    """The compiled pass of the UKF's points against the same arithmetic in numpy: a rejected channel is
    counted and not summed, an unusable one neither."""
    rng = np.random.default_rng(1)
    S, m = 6, 4
    Ad = np.eye(6) + 0.01 * rng.standard_normal((S, m, 6, 6))
    Bd = 0.01 * rng.standard_normal((S, m, 6, 1))
    X0 = rng.standard_normal((S, 6))
    C, D = rng.standard_normal((S, 4, 6)), rng.standard_normal((S, 4))
    delta, delta_now = rng.standard_normal(m), rng.standard_normal(m)
    shift, y_offset = 0.1 * rng.standard_normal(S), 0.1 * rng.standard_normal((S, 4))
    Wm = Wc = np.full(S, 1 / S)
    R = np.full(4, 0.01)
    observed = np.array([True, False, True, True])
    mask = np.array([[True] * 4, [False] * 4, [True, True, False, True], [True] * 4])
    X = X0.copy()
    truth_y = []
    for k in range(m):
        X = np.einsum("sij,sj->si", Ad[:, k], X) + Bd[:, k, :, 0] * (delta[k] + shift)[:, None]
        truth_y.append(np.einsum("sij,sj->si", C, X) + D * (delta_now[k] + shift)[:, None] + y_offset)
    values = np.array([Wm @ y for y in truth_y])
    values[3, 0] += 100.0  # a spike
    sum_y, sum_z, n, rejected = np.zeros((S, 4)), np.zeros(4), np.zeros(4), np.zeros(4, dtype=np.int64)
    Xc = X0.copy()
    w = np.column_stack([delta, np.zeros((m, 3))])  # the hold's inputs
    sigma_pass(Ad, Bd, np.arange(m), Xc, w, delta_now, observed, values, mask, C, D, shift, y_offset,
               np.zeros((S, 4)), np.zeros((S, 4, 6)), np.zeros((S, 4)), Wm, Wc, R, 25.0, sum_y, sum_z, n, rejected)
    np.testing.assert_allclose(Xc, X, rtol=1e-12, atol=1e-14)
    np.testing.assert_array_equal(rejected, [1, 0, 0, 0])
    np.testing.assert_array_equal(n, [2, 3, 2, 3])
    expected = truth_y[0] + truth_y[2] * mask[2] + truth_y[3] * np.array([0, 1, 1, 1])
    np.testing.assert_allclose(sum_y, expected, rtol=1e-12, atol=1e-14)
