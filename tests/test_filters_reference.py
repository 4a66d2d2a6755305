"""The EKF's fast path against a plain per-sample filterpy ExtendedKalmanFilter (the oracle).

The reference below is the textbook augmented-state EKF, built here from the model's functions only
(online_id.model: exact discretisation with its θ-derivatives, outputs and their θ-Jacobian): every
sample it predicts x ← Ad x + Γ w with F = [[Ad, ∂(Ad x + Γ w)/∂s], [0, I]], P ← F P Fᵀ + Q, then
updates with that sample's measurements. w is the step's input between its two samples
(online_id/model/intersample.py, from the whole run's samples: ``run_inputs``): the hold's [δ, 0, 0, 0]
(Γ w = Bd δ), or the cubic's value and derivatives, whose columns Γ and their θ-derivatives it takes from
expm of the augmented generator (``input_columns``; Van Loan: ``input_column_derivatives``), at each step's
own θ and speed (the cubic's: the mean of its two samples'). A step that skipped samples
(online_id/stream/gaps.py: longer than 1.5 nominal periods) it predicts as the estimator does on purpose,
in nominal sub-steps (x and F chained through them, Q over the whole step): the hold's with δ interpolated
across the gap, the cubic's along its own curve (``split_step``): the jittered runs below drop samples
(a 4 ms step against a 2-3 ms median period is bridged), and holding δ there would be a different filter,
not a slower one.
With ``correct_every=1`` (every block one sample) and the
adaptive parts switched off (no tempering, no covariance matching, one random walk, a wide gate),
:class:`EKFEstimator` must follow it: its groups, spectral steps (first order in speed and
parameters), running sums and block update from the block-start state are all speed, none of them is a different filter.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from filterpy.kalman import ExtendedKalmanFilter

from online_id.filters import EKFEstimator, FilterConfig
from online_id.model import intersample as its
from online_id.model.discretise import continuous_derivatives, discretise_with_sensitivity
from online_id.model.lateral import N_STATES, output_matrices, output_parameter_jacobian, outputs
from online_id.sim.simulator import SensorNoise, simulate
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
    """The plain per-sample augmented EKF with filterpy, from the model functions; ``samples``: the whole run
    (the cubic's input at a step needs the sample after it)."""

    def __init__(self, car, est: EKFEstimator, samples, kind="hold"):
        self.car, self.known, self.theta0 = car, car.known, est.theta0
        self.kind = kind
        t = np.array([s.time for s in samples])
        self.W, self.S = its.run_inputs(kind, t, np.array([s.steering_wheel_angle for s in samples])
                                        / car.known.steering_ratio, np.array([s.speed for s in samples]))
        self.k = 0  # the next sample's row
        self.kf = ExtendedKalmanFilter(dim_x=len(est.x), dim_z=4)  # (the four channels these runs log)
        self.kf.x = est.x.copy()
        self.kf.P = est.P.copy()
        self.R = np.diag([CONFIG.measurement_std[c] ** 2 for c in MEASURED_CHANNELS[:4]])
        self.q_state = np.asarray(CONFIG.state_process_std) ** 2
        self.q_param = CONFIG.parameter_random_walk ** 2
        self.last = None
        self.clock = SampleClock()

    def theta(self, x):
        return self.theta0 * np.exp(x[N_STATES:])

    def update(self, sample):
        delta, V = sample.steering_wheel_angle / self.known.steering_ratio, sample.speed
        k, self.k = self.k, self.k + 1
        if self.last is not None:
            t0, delta0, V0 = self.last
            dt = sample.time - t0
            missing = self.clock.missing(dt)
            self.clock.observe(dt)
            if self.kind == "hold":
                h, deltas = bridge_inputs(dt, missing, delta0, delta)  # (dt, [δ0]) when none missing
                parts = [np.array([d, 0.0, 0.0, 0.0]) for d in deltas]
            else:
                h, parts = dt / (missing + 1), its.split_step(self.W[k], missing + 1)
            self.predict(h, parts, self.S[k])
            self.correct(sample, delta, V)
        self.last = (sample.time, delta, V)

    def predict(self, h, parts, V):
        """One sample step in len(parts) exact sub-steps of h [s] with inputs ``parts`` (each (4,)): x and the
        chained F through them, then P ← F P Fᵀ + Q over the whole step (as the estimator: Q over the time
        since the last update)."""
        kf, n = self.kf, N_STATES
        x = kf.x.copy()
        theta = self.theta(x)
        Ad, Bd, dAd, dBd = discretise_with_sensitivity(theta, V, self.known, h)
        if self.kind != "hold":  # the input polynomial's columns Γ (6, 4) and their θ-derivatives (8, 6, 4)
            Ac, Bc, dAc, dBc, _, _ = continuous_derivatives(theta, V, self.known)
            Gamma = its.input_columns(Ac, Bc, h)
            dGamma = its.input_column_derivatives(Ac, Bc, dAc, dBc, h)
        F = np.eye(len(x))
        for w in parts:
            step = np.eye(len(x))
            step[:n, :n] = Ad
            if self.kind == "hold":
                delta = w[0]
                step[:n, n:] = (np.einsum("kij,j->ik", dAd, x[:n]) + dBd.T * delta) * theta  # ∂/∂s = θ ∂/∂θ
                x[:n] = Ad @ x[:n] + Bd * delta
            else:
                step[:n, n:] = (np.einsum("kij,j->ik", dAd, x[:n]) + np.einsum("kij,j->ik", dGamma, w)) * theta
                x[:n] = Ad @ x[:n] + Gamma @ w
            F = step @ F
        dt = h * len(parts)
        kf.F = F
        kf.Q = np.diag(np.concatenate([self.q_state * dt, np.full(len(x) - n, self.q_param * dt)]))
        kf.predict()  # P ← F P Fᵀ + Q (and x ← F x, replaced by the exact steps next)
        kf.x = x

    def correct(self, sample, delta, V):
        n = N_STATES
        z = np.array(sample.measurements()[:4], dtype=float)  # (these runs log the four channels, no v_y)

        def H(x):
            theta = self.theta(x)
            C, _ = output_matrices(theta, V, self.known)
            return np.hstack([C, output_parameter_jacobian(x[:n], delta, theta, V, self.known) * theta])[:4]

        def h(x):
            return outputs(x[:n], delta, self.theta(x), V, self.known)[:4]

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


def _logged(run, idx, seed):
    """Rows ``idx`` of a noise-free run with the sensors' noise added after sampling (as a logger sees a car)."""
    noise, rng = SensorNoise(), np.random.default_rng(seed)
    columns = {name: getattr(run, name)[idx] for name in ("time", "steering_wheel_angle", "speed")}
    for name in ("yaw_rate", "lateral_acceleration", "roll_angle", "roll_rate"):
        columns[name] = getattr(run, name)[idx] + rng.normal(0.0, getattr(noise, name), len(idx))
    return list(samples_from_run(replace(run, **columns)))


@pytest.fixture(scope="module")
def runs(car):
    truth = car.truth("track")
    steady = list(samples_from_run(simulate(car, truth, duration_s=1.5, seed=11).run))
    t = np.arange(4000) * 1e-3
    swing = 80 / 3.6 * (1 + 0.2 * np.sin(2 * np.pi * t / 1.0))  # ±20 % within a second
    varying = _jittered(simulate(car, truth, duration_s=4.0, speed_mps=swing, seed=12).run,
                        np.random.default_rng(5), 4)
    # a 100 Hz logger on a car simulated at 1 kHz: every 10th sample; and one whose period jitters 8-12 ms
    # (with every 25th step a lost sample, bridged) while the speed swings ±20 % within 2 s
    fine = simulate(car, truth, duration_s=6.0, noise=SensorNoise.none(), seed=13).run
    logger = _logged(fine, np.arange(0, len(fine), 10), 14)
    t = np.arange(8000) * 1e-3
    swing = 80 / 3.6 * (1 + 0.2 * np.sin(2 * np.pi * t / 2.0))
    fine = simulate(car, truth, duration_s=8.0, speed_mps=swing, noise=SensorNoise.none(), seed=15).run
    rng = np.random.default_rng(16)
    steps = rng.integers(8, 13, size=len(fine) // 8)
    steps[24::25] *= 2
    idx = np.cumsum(steps)
    jittery = _logged(fine, idx[idx < len(fine)], 17)
    return {"constant speed, 1 kHz": steady, "speed ±20 %, period 1-4 ms": varying,
            "constant speed, 100 Hz": logger, "speed ±20 %, period 8-12 ms": jittery}


#: (run, intersample model) of the comparison: the hold on the 1 kHz runs (the filter the project was built
#: with), the cubic on all four (its steps exact for the input between samples, also at a logger's rate).
RUNS = ("constant speed, 1 kHz", "speed ±20 %, period 1-4 ms", "constant speed, 100 Hz", "speed ±20 %, period 8-12 ms")
CASES = [(run, kind) for kind in ("hold", "cubic") for run in RUNS if kind == "cubic" or run in RUNS[:2]]


@pytest.mark.parametrize("which,kind", CASES)
def test_fast_ekf_follows_the_plain_per_sample_filterpy_ekf(car, runs, which, kind):
    samples = runs[which]
    est = EKFEstimator(car, config=replace(CONFIG, intersample=kind))
    ref = _ReferenceEKF(car, est, samples, kind)
    for s in samples:
        est.update(s)
        ref.update(s)
    est.finish()  # (the cubic works each sample when the next has come: the last one now)
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
    # 0.2 s blocks, the span this guards (the default span is 50 ms since issue 36: FilterConfig.max_block_s)
    est = EKFEstimator(load_vehicle("revs_250lm"), config=FilterConfig(max_block_s=0.2))
    for s in samples:
        est.update(s)
    assert est.events["corrections"] > 1000
    assert not est.reset_reasons, dict(est.reset_reasons)
    assert np.all(np.isfinite(est.P)) and np.all(np.linalg.eigvalsh(est.P) > 0)
