"""The EKF's fast path against a plain per-sample filterpy ExtendedKalmanFilter (the oracle).

The reference below is the textbook augmented-state EKF, built here from the model's functions only
(online_id.model: exact discretisation with its θ-derivatives, outputs and their θ-Jacobian): every
sample it predicts x ← Ad x + Bd δ with F = [[Ad, ∂(Ad x + Bd δ)/∂s], [0, I]], P ← F P Fᵀ + Q, then
updates with that sample's measurements. With ``correct_every=1`` (every block one sample) and the
adaptive parts switched off (no tempering, no covariance matching, one random walk, a wide gate),
:class:`EKFEstimator` must follow it: its groups, spectral steps (first order in speed and
parameters), running sums and block-end mapping are all speed, none of them is a different filter.
"""

from __future__ import annotations

import numpy as np
import pytest
from filterpy.kalman import ExtendedKalmanFilter

from online_id.filters import EKFEstimator, FilterConfig
from online_id.model.discretise import discretise_with_sensitivity
from online_id.model.lateral import N_STATES, output_matrices, output_parameter_jacobian, outputs
from online_id.samples import MEASURED_CHANNELS, samples_from_run
from online_id.sim.simulator import simulate
from online_id.vehicle import load_vehicle

#: The same filter on both sides: one sample per correction, nothing adaptive.
CONFIG = FilterConfig(correct_every=1, converging_r_scale=1.0, adaptive_r_window_s=0.0,
                      converging_random_walk=FilterConfig().parameter_random_walk, gate_sigma=1e3)

#: How close the fast path must stay to the reference after the run. Its steps are first order in the
#: parameters' and the speed's distance from the linearisation point (error ≤ 2e-4 of a step, see
#: filters/local_model.py) and its parameter columns are those at that point, so it is not bit-equal:
#: the parameters within 2 % of their own σ, the model states within 2 % of theirs, every variance
#: within 2 %.
PARAMETER_TOL_SIGMA = 0.02
STATE_TOL_SIGMA = 0.02
VARIANCE_RTOL = 0.02


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

    def theta(self, x):
        return self.theta0 * np.exp(x[N_STATES:])

    def update(self, sample):
        delta, V = sample.steering_wheel_angle / self.known.steering_ratio, sample.speed
        if self.last is not None:
            t0, delta0, V0 = self.last
            self.predict(sample.time - t0, delta0, V0)
            self.correct(sample, delta, V)
        self.last = (sample.time, delta, V)

    def predict(self, dt, delta, V):
        kf, n = self.kf, N_STATES
        x = kf.x
        theta = self.theta(x)
        Ad, Bd, dAd, dBd = discretise_with_sensitivity(theta, V, self.known, dt)
        F = np.eye(len(x))
        F[:n, :n] = Ad
        F[:n, n:] = (np.einsum("kij,j->ik", dAd, x[:n]) + dBd.T * delta) * theta  # ∂/∂s = θ ∂/∂θ
        x_new = x.copy()
        x_new[:n] = Ad @ x[:n] + Bd * delta
        kf.F = F
        kf.Q = np.diag(np.concatenate([self.q_state * dt, np.full(len(x) - n, self.q_param * dt)]))
        kf.predict()  # P ← F P Fᵀ + Q (and x ← F x, replaced by the exact step next)
        kf.x = x_new

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
    assert np.all(np.abs(x[n:] - xr[n:]) < PARAMETER_TOL_SIGMA * sd[n:]), (x[n:] - xr[n:]) / sd[n:]
    assert np.all(np.abs(x[:n] - xr[:n]) < STATE_TOL_SIGMA * sd[:n]), (x[:n] - xr[:n]) / sd[:n]
    np.testing.assert_allclose(np.diag(P), np.diag(Pr), rtol=VARIANCE_RTOL)
    # and the run taught something: the reference's parameters moved well away from the prior
    assert np.max(np.abs(xr[n:])) > 0.05
