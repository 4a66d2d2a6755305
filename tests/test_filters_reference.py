"""The EKF's fast path against a plain per-sample filterpy ExtendedKalmanFilter (the oracle).

The reference below is the textbook augmented-state EKF, built here from the model's functions only
(online_id.model: exact discretisation with its θ-derivatives, outputs and their θ-Jacobian): every
sample it predicts x ← Ad x + Bd δ with F = [[Ad, ∂(Ad x + Bd δ)/∂s], [0, I]], P ← F P Fᵀ + Q, then
updates with that sample's measurements. A step that skipped samples (online_id/stream/gaps.py: longer
than 1.5 nominal periods) it predicts as the estimator does on purpose, in nominal sub-steps with δ
interpolated across the gap (x and F chained through them, Q over the whole step): the jittered run
below drops samples of a 1 kHz run (a 4 ms step against a 2-3 ms median period is bridged), and
holding δ there would be a different filter, not a slower one.
With ``correct_every=1`` (every block one sample) and the
adaptive parts switched off (no tempering, no covariance matching, one random walk, a wide gate),
:class:`EKFEstimator` must follow it: its groups, spectral steps (first order in speed and
parameters), running sums and block update from the block-start state are all speed, none of them is a different filter.
"""

from __future__ import annotations

import numpy as np
import pytest
from filterpy.kalman import ExtendedKalmanFilter

from online_id.filters import EKFEstimator, FilterConfig
from online_id.model.discretise import discretise_with_sensitivity
from online_id.model.lateral import N_STATES, output_matrices, output_parameter_jacobian, outputs
from online_id.sim.simulator import simulate
from online_id.stream.gaps import SampleClock, bridge_inputs
from online_id.stream.samples import MEASURED_CHANNELS, samples_from_run
from online_id.vehicle import load_vehicle

#: The same filter on both sides: one sample per correction, nothing adaptive.
CONFIG = FilterConfig(correct_every=1, converging_r_scale=1.0, adaptive_r_window_s=0.0,
                      converging_random_walk=FilterConfig().parameter_random_walk, gate_sigma=1e3,
                      linear_range_ay=np.inf)  # the oracle learns from every sample

#: How close the fast path must stay to the reference after the run. Its steps are first order in the
#: parameters' and the speed's distance from the linearisation point (error ≤ 2e-4 of a step, see
#: filters/local_model.py) and its parameter columns are those at that point, so it is not bit-equal:
#: the parameters within 2 % of their own σ, the model states within 2 % of theirs, every variance
#: within 2 %.
PARAMETER_TOL_SIGMA = 0.02
STATE_TOL_SIGMA = 0.02
VARIANCE_RTOL = 0.02
#: On the ±20 % speed swing the parameters' columns of a step stay those of the linearisation speed
#: (the step itself is corrected to first order in speed, its θ-derivatives are not): after 4000
#: samples with speed_tolerance 0.02 the parameters end 0.07-0.09 of their σ from the oracle
#: (2026-11-23), and 0.0000 σ with a linearisation at every speed. Bounded here at 0.15 σ: a step
#: without the speed correction is 300× further from exact (2.9e-3 against 9e-6 of ‖Φ − I‖ at 2 %),
#: and the test is still far below the filter's own σ. The model states likewise.
PARAMETER_TOL_SIGMA_VARYING_SPEED = 0.15


class _ReferenceEKF:
    """The plain per-sample augmented EKF with filterpy, from the model functions."""

    def __init__(self, car, est: EKFEstimator):
        self.car, self.known, self.theta0 = car, car.known, est.theta0
        self.kf = ExtendedKalmanFilter(dim_x=len(est.x), dim_z=len(MEASURED_CHANNELS))
        self.kf.x = est.x.copy()
        self.kf.P = est.P.copy()
        self.R = np.diag([CONFIG.measurement_std[c] ** 2 for c in MEASURED_CHANNELS])
        self.q_state = np.asarray(CONFIG.state_process_std) ** 2
        self.q_param = CONFIG.parameter_random_walk ** 2
        self.last = None
        self.clock = SampleClock()

    def theta(self, x):
        return self.theta0 * np.exp(x[N_STATES:])

    def update(self, sample):
        delta, V = sample.steering_wheel_angle / self.known.steering_ratio, sample.speed
        if self.last is not None:
            t0, delta0, V0 = self.last
            dt = sample.time - t0
            missing = self.clock.missing(dt)
            self.clock.observe(dt)
            self.predict(*bridge_inputs(dt, missing, delta0, delta), V0)  # (dt, [δ0]) when none missing
            self.correct(sample, delta, V)
        self.last = (sample.time, delta, V)

    def predict(self, h, deltas, V):
        """One sample step in len(deltas) exact sub-steps of h [s]: x and the chained F through them,
        then P ← F P Fᵀ + Q over the whole step (as the estimator: Q over the time since the last update)."""
        kf, n = self.kf, N_STATES
        x = kf.x.copy()
        theta = self.theta(x)
        Ad, Bd, dAd, dBd = discretise_with_sensitivity(theta, V, self.known, h)
        F = np.eye(len(x))
        for delta in deltas:
            step = np.eye(len(x))
            step[:n, :n] = Ad
            step[:n, n:] = (np.einsum("kij,j->ik", dAd, x[:n]) + dBd.T * delta) * theta  # ∂/∂s = θ ∂/∂θ
            F = step @ F
            x[:n] = Ad @ x[:n] + Bd * delta
        dt = h * len(deltas)
        kf.F = F
        kf.Q = np.diag(np.concatenate([self.q_state * dt, np.full(len(x) - n, self.q_param * dt)]))
        kf.predict()  # P ← F P Fᵀ + Q (and x ← F x, replaced by the exact steps next)
        kf.x = x

    def correct(self, sample, delta, V):
        n = N_STATES
        z = np.array(sample.measurements(), dtype=float)

        def H(x):
            theta = self.theta(x)
            C, _ = output_matrices(theta, V, self.known)
            return np.hstack([C, output_parameter_jacobian(x[:n], delta, theta, V, self.known) * theta])

        def h(x):
            return outputs(x[:n], delta, self.theta(x), V, self.known)

        self.kf.update(z, HJacobian=H, Hx=h, R=self.R)
        self.kf.P = 0.5 * (self.kf.P + self.kf.P.T)


def _jittered(run, rng, max_step):
    """Samples of ``run`` at irregular indices (steps of 1..max_step samples): a jittering period."""
    samples = list(samples_from_run(run))
    idx = np.cumsum(rng.integers(1, max_step + 1, size=len(samples)))
    return [samples[i] for i in idx[idx < len(samples)]]


@pytest.fixture(scope="module")
def car():
    return load_vehicle("haro2008")


def _runs(car):
    truth = car.truth("track")
    steady = list(samples_from_run(simulate(car, truth, duration_s=1.5, seed=11).run))
    t = np.arange(4000) * 1e-3
    swing = 80 / 3.6 * (1 + 0.2 * np.sin(2 * np.pi * t / 1.0))  # ±20 % within a second
    varying = _jittered(simulate(car, truth, duration_s=4.0, speed_mps=swing, seed=12).run,
                        np.random.default_rng(5), 4)
    return {"constant speed, 1 kHz": steady, "speed ±20 %, period 1-4 ms": varying}


@pytest.mark.parametrize("which", ["constant speed, 1 kHz", "speed ±20 %, period 1-4 ms"])
def test_fast_ekf_follows_the_plain_per_sample_filterpy_ekf(car, which):
    samples = _runs(car)[which]
    est = EKFEstimator(car, config=CONFIG)
    ref = _ReferenceEKF(car, est)
    for s in samples:
        est.update(s)
        ref.update(s)
    assert est.events["corrections"] == len(samples) - 1 and est.events.get("resets", 0) == 0
    x, P = est.x, est.P
    xr, Pr = ref.kf.x, ref.kf.P
    sd = np.sqrt(np.diag(Pr))
    n = N_STATES
    tol = PARAMETER_TOL_SIGMA if which.startswith("constant") else PARAMETER_TOL_SIGMA_VARYING_SPEED
    assert np.all(np.abs(x[n:] - xr[n:]) < tol * sd[n:]), (x[n:] - xr[n:]) / sd[n:]
    tol = STATE_TOL_SIGMA if which.startswith("constant") else PARAMETER_TOL_SIGMA_VARYING_SPEED
    assert np.all(np.abs(x[:n] - xr[:n]) < tol * sd[:n]), (x[:n] - xr[:n]) / sd[:n]
    np.testing.assert_allclose(np.diag(P), np.diag(Pr), rtol=VARIANCE_RTOL)
    # and the run taught something: the reference's parameters moved well away from the prior
    assert np.max(np.abs(xr[n:])) > 0.05


def test_the_block_update_stays_well_posed_on_the_100_hz_race_car_log():
    """At 100 Hz a block of 20 samples lasts 0.2 s, in which the tyre lags decay by ~e⁻⁴⁰: the block
    transition F is singular to round-off. The update must not invert it (filters/ekf.py): mapping the
    block means through F⁻¹ gave S with rcond 1e-20 and 15 resets on this log (LinAlgError, singular
    block transition). Real data: ../shared/realdata/revs_250lm (the car is past the model; the verdict
    says so elsewhere, the filter itself must stay well posed)."""
    from online_id.io.tracklog import read_track_run
    from tests.conftest import SHARED

    log = SHARED / "realdata" / "revs_250lm" / "revs_250lm_laps_0-400s.csv"
    if not log.exists():
        pytest.fail(f"the real-data log is missing: {log} (shared/ must sit beside the checkout)")
    samples = list(samples_from_run(read_track_run(log)))
    est = EKFEstimator(load_vehicle("revs_250lm"))
    for s in samples:
        est.update(s)
    assert est.events["corrections"] > 1000
    assert not est.reset_reasons, dict(est.reset_reasons)
    assert np.all(np.isfinite(est.P)) and np.all(np.linalg.eigvalsh(est.P) > 0)
