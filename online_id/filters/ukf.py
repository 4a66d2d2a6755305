"""Augmented-state unscented Kalman filter on filterpy's :class:`UnscentedKalmanFilter`.

Sigma points are filterpy's :class:`MerweScaledSigmaPoints` with α = 1, β = 0,
κ = 0: 2n points at ±√n σ with equal positive weights and no centre point (the
spherical-cubature rule). Positive weights keep the predicted covariance
positive semi-definite, which negative-weight settings (small α) do not for a
14-dimensional state.

All sigma points are propagated in one batched call: each gets its own
exact discretisation per run of samples within ``speed_tolerance`` of one speed
(exact in each sample's period, first order in its speed: the same steps and
error bounds as the EKF's, filters/local_model.py), x ← Ad x + Γ w with w the
step's input between its samples (:mod:`online_id.model.intersample`; Γ_j =
h φ_j+1(Ac h) Bc, one column for ``FilterConfig.intersample`` "hold", whose
numbers are the zero-order hold's of before issue 36, four for the cubic), from
expm of its generator (for the cubic, augmented with the input's chain) and the
derivative in V by a compiled Padé approximant where the run has few periods (a
log at one rate), else from one eigen-decomposition per sigma point
(filters/sigma_block.py states the error), and is advanced through the samples
of the block. On the way each sigma point's outputs are
computed at every sample; a sample is gated per channel against the spread of
its sigma-point outputs, and the accepted ones are averaged per sigma point.
filterpy's unscented transform then forms the predicted mean and covariance,
and the correction relates the block means to the block-end state through the
same (propagated) sigma points.

Extra states e (offsets, effect parameters; :mod:`online_id.filters.augment`) are carried by the
sigma points like the parameters: each point's input curve is shifted by g·e (its value only) and it reads its
outputs as C x + D δ + M e + Σ e_i K_i x (δ + g·e at the sample), less (τ_i − τ̂)·ẏ on the channels a delay τ
lags (read at the mean's τ̂, :mod:`online_id.filters.lagged`).
"""

from __future__ import annotations

import numpy as np

from online_id.filters._filterpy import MerweScaledSigmaPoints, UnscentedKalmanFilter, unscented_transform
from online_id.filters.base import N_AUG, PARAMS, OnlineEstimator
from online_id.filters.config import UKF_MAX_BLOCK_S
from online_id.filters.local_model import SAMPLE_PERIOD_TOLERANCE
from online_id.filters.sigma_block import compile_now as compile_sigma_block
from online_id.filters.sigma_block import sigma_expm_steps, sigma_pass, sigma_steps, step_plan
from online_id.model.discretise import discretise_continuous, spectral_form, speed_generators
from online_id.model.lateral import N_OUTPUTS, N_STATES, continuous_matrices, outputs_from_continuous

#: Up to this many runs of one sample period in a run of samples, each sigma point is discretised by expm
#: (Padé, compiled) once per run; above it, by one eigen-decomposition for all of them (see
#: ``UKFEstimator._segment_steps``). An expm with its derivative costs about a third of a decomposition.
EXPM_PERIODS_MAX = 3

#: The input columns Γ_j a step's input w uses, by intersample model (model/intersample.py): the hold's w is
#: [δ, 0, 0, 0], the linear's [δ, Δδ, 0, 0].
INPUT_COLUMNS = {"hold": 1, "linear": 2, "cubic": 4}

_FIRST = np.zeros(1, dtype=np.int64)  # the first sample of a run of one step
_NO_SPEED_CHANGE = np.zeros((1, 1))  # a step at its generator's own speed
_NO_VALUES = np.zeros((1, N_OUTPUTS))  # an unobserved sample's row of values and mask (not read)
_NO_MASK = np.zeros((1, N_OUTPUTS), dtype=bool)


def _unscented_transform(sigmas, Wm, Wc, noise_cov):
    """filterpy's ``unscented_transform`` (plain mean and residual, as the prediction uses it) without the
    (2n + 1, 2n + 1) matrix diag(Wc) it multiplies by: Wc_k y_k scales each row instead (the product's other
    terms are exact zeros). The predicted state and covariance came out bit-identical on the built-in run; the
    block's few outputs did not always (BLAS sums a 4-column product in another order), so those keep
    filterpy's own."""
    x = np.dot(Wm, sigmas)
    y = sigmas - x[np.newaxis, :]
    P = np.dot(y.T, Wc[:, None] * y)
    P += noise_cov
    return x, P


class _SigmaPoints(MerweScaledSigmaPoints):
    """filterpy's Merwe points, the 2n + 1 rows x, x + U_k, x − U_k formed in two array operations instead of
    2n (the same numbers: filterpy forms x − (−U_k) and x − U_k)."""

    def sigma_points(self, x, P):
        n = self.n
        if np.size(x) != n:
            raise ValueError(f"expected size(x) {n}, but size is {np.size(x)}")
        lambda_ = self.alpha ** 2 * (n + self.kappa) - n
        U = self.sqrt((lambda_ + n) * np.atleast_2d(P))
        sigmas = np.empty((2 * n + 1, n))
        sigmas[0] = x
        sigmas[1:n + 1] = x - (-U)
        sigmas[n + 1:] = x - U
        return sigmas


class _BatchUKF(UnscentedKalmanFilter):
    """filterpy's UKF with the process model applied to all sigma points at once."""

    def compute_process_sigmas(self, dt, fx=None, **fx_args):
        sigmas = self.points_fn.sigma_points(self.x, self.P)
        self.sigmas_f = fx(sigmas, **fx_args)

    def predict(self, dt=None, UT=None, fx=None, **fx_args):
        """filterpy's ``predict`` (the same arithmetic) less the sigma points of the predicted state it forms at
        the end, which nothing here reads; their square root is still taken, so that a predicted covariance that
        is not positive-definite raises here, and resets the filter, as before."""
        self.compute_process_sigmas(dt, fx, **fx_args)
        self.x, self.P = _unscented_transform(self.sigmas_f, self.Wm, self.Wc, self.Q)
        points = self.points_fn
        n = points.n
        points.sqrt((points.alpha ** 2 * (n + points.kappa) - n + n) * self.P)
        self.x_prior = np.copy(self.x)
        self.P_prior = np.copy(self.P)


class UKFEstimator(OnlineEstimator):
    """Augmented-state UKF. See :class:`~online_id.filters.base.OnlineEstimator` for the API."""

    name = "ukf"
    max_block_s = UKF_MAX_BLOCK_S

    def _init_filter(self, x0, P0):
        if type(self)._propagate_sigmas is UKFEstimator._propagate_sigmas:  # (a variant with its own step: not)
            compile_sigma_block()  # (a live run must not stall at its first block)
        points = _SigmaPoints(self.n_aug, alpha=1.0, beta=0.0, kappa=0.0, sqrt_method=self._covariance_sqrt)
        self._kf = _BatchUKF(dim_x=self.n_aug, dim_z=4, dt=1e-3, hx=None, fx=None, points=points)
        self._kf.x = x0.copy()
        self._kf.P = P0.copy()
        self._start_block()

    @property
    def x(self):
        return self._kf.x

    @property
    def P(self):
        return self._kf.P

    def _set(self, x, P):
        self._kf.x = x
        self._kf.P = P
        self._start_block()

    def _start_block(self):
        # the block's samples, in columns: period, V over the step, δ now, V now (lists), whether observed
        # (list), and in row blocks ((m_i, ·) arrays) the steps' inputs w, the measured values and usable mask
        # (an unobserved sample's not read)
        self._dt: list[float] = []
        self._w: list[np.ndarray] = []
        self._speed_held: list[float] = []
        self._delta_now: list[float] = []
        self._speed_now: list[float] = []
        self._observed: list[bool] = []
        self._values: list[np.ndarray] = []
        self._masks: list[np.ndarray] = []
        self._block = None
        self._block_sums = None

    def _propagate(self, dt, w, speed):
        self._dt.append(dt)
        self._w.append(w[None])
        self._speed_held.append(speed)
        self._delta_now.append(float(w[0]))  # (read only where observed, as ``_observe`` sets them)
        self._speed_now.append(speed)
        self._observed.append(False)
        self._values.append(_NO_VALUES)
        self._masks.append(_NO_MASK)

    def _observe(self, values, mask, delta, speed):
        self._observed[-1] = True
        self._values[-1] = np.asarray(values, dtype=float).reshape(1, N_OUTPUTS)
        self._masks[-1] = mask.reshape(1, N_OUTPUTS)
        self._delta_now[-1], self._speed_now[-1] = delta, speed

    def _propagate_observe_many(self, dt, w, speed_held, values, mask, delta, speed, observe):
        """What ``_propagate`` and ``_observe`` do sample by sample, in one step: the columns extended, the
        values (m, 4) and mask kept as one row block (an unobserved sample's row is not read)."""
        self._dt.extend(dt)
        self._w.append(w)
        self._speed_held.extend(speed_held)
        self._delta_now.extend(delta)  # (read only where observed, as ``_observe`` sets them)
        self._speed_now.extend(speed)
        self._observed.extend(observe)
        self._values.append(np.asarray(values, dtype=float))
        self._masks.append(mask[None].repeat(len(dt), axis=0))

    def _buffered(self):
        """The block's columns as arrays: dt, the steps' inputs w (m, 4), V over each step, δ now, observed,
        values (m, 4), mask (m, 4)."""
        values = self._values[0] if len(self._values) == 1 else np.concatenate(self._values)
        mask = self._masks[0] if len(self._masks) == 1 else np.concatenate(self._masks)
        w = self._w[0] if len(self._w) == 1 else np.concatenate(self._w)
        return (np.array(self._dt), np.ascontiguousarray(w, dtype=float), np.array(self._speed_held),
                np.array(self._delta_now), np.array(self._observed, dtype=bool), values, mask)

    def _buffered_samples(self):
        """The block's samples one by one: (dt, w (4,), V over the step, values (4,) or None, mask (4,) or None,
        δ now, V now), None where a sample was not observed."""
        values = np.concatenate(self._values) if self._values else np.zeros((0, N_OUTPUTS))
        mask = np.concatenate(self._masks) if self._masks else np.zeros((0, N_OUTPUTS), dtype=bool)
        w = np.concatenate(self._w) if self._w else np.zeros((0, 4))
        for k, seen in enumerate(self._observed):
            yield (self._dt[k], w[k], self._speed_held[k], values[k] if seen else None,
                   mask[k] if seen else None, self._delta_now[k], self._speed_now[k])

    def _segments(self):
        """Runs of buffered samples whose speeds stay within ``speed_tolerance`` of the run's first."""
        speeds, tol = self._speed_held, self.config.speed_tolerance
        i = 0
        while i < len(speeds):
            V = speeds[i]
            j = i + 1
            while j < len(speeds) and abs(speeds[j] - V) <= tol * V:
                j += 1
            yield i, j, V
            i = j

    def _segment_steps(self, thetas, dt, V, V_ref, lagged=True):
        """Ad (S, r, 6, 6) and the input columns Γ (S, r, 6, q) of every sigma point's parameters ``thetas``
        (S, 8) for the r distinct steps of the samples of periods ``dt`` (m,) at step speeds ``V`` (m,), each
        sample's row among them (m,) (filters/sigma_block.py ``step_rows``), the outputs C (S, 4, 6), D (S, 4)
        (independent of V), and their rates ẏ = C·Ac x + C·Bc δ as (C·Ac (S, 4, 6), C·Bc (S, 4)) at V_ref (a
        delay's sensitivity, filters/lagged.py; without ``lagged`` zeros, not read). q = :data:`INPUT_COLUMNS`
        of the intersample model (Γ_0 = Bd: the hold's one column).

        Exact in each sample's period and first order in its speed's distance from V_ref
        (filters/local_model.py states the error). Samples of a few periods (a log at one rate: its time
        stamps differ in their last bits): each point's expm and its derivative in V at each period, by Padé
        in compiled code (filters/sigma_block.py ``sigma_expm_steps``). Many periods (a jittering log): one
        eigen-decomposition per point gives every period's Φ more cheaply (``sigma_steps``); where a
        decomposition is ill-conditioned, expm per sample at the sample's own speed (:meth:`_exact_steps`).
        """
        G, dG = speed_generators(thetas, V_ref, self.known)
        if not np.isfinite(G.sum()):  # (as numpy's eig did: the correction resets the filter)
            raise np.linalg.LinAlgError("Array must not contain infs or NaNs")
        Ac, Bc = G[:, :N_STATES, :N_STATES], G[:, :N_STATES, N_STATES]
        C, D = outputs_from_continuous(Ac, Bc, np.full(len(thetas), V_ref), per_unit_speed=True)
        S, m = len(thetas), len(dt)
        q = INPUT_COLUMNS[self.config.intersample]
        no_rates = (np.zeros((S, N_OUTPUTS, N_STATES)), np.zeros((S, N_OUTPUTS)))
        rates = (C @ Ac, np.einsum("sij,sj->si", C, Bc)) if lagged else no_rates
        c = (V - V_ref)[:, None]
        rows = np.empty(m, dtype=np.int64)
        r, periods = step_plan(dt, c, SAMPLE_PERIOD_TOLERANCE, rows)
        if periods <= EXPM_PERIODS_MAX:
            first = np.flatnonzero(np.diff(rows, prepend=-1)) if r > 1 else _FIRST  # each row's first sample
            Ad, Gam = np.empty((S, r, N_STATES, N_STATES)), np.empty((S, r, N_STATES, q))
            sigma_expm_steps(G, dG[:, None], dt[first], c[first], SAMPLE_PERIOD_TOLERANCE, Ad, Gam)
            return Ad, Gam, rows, C, D, rates
        every = np.arange(m)
        dAc_V, dBc_V = dG[:, :N_STATES, :N_STATES], dG[:, :N_STATES, N_STATES]
        form = spectral_form(Ac, Bc, dAc_V[:, None], dBc_V[:, None])
        if form.usable:
            Ad, Gam = np.empty((S, m, N_STATES, N_STATES)), np.empty((S, m, N_STATES, q))
            sigma_steps(form.eigenvalues, form.vectors, form.inverse, form.directions, dt, c,
                        SAMPLE_PERIOD_TOLERANCE, Ad, Gam)
            return Ad, Gam, every, C, D, rates
        return (*self._exact_steps(thetas, dt, V, q), every, C, D, rates)

    def _exact_steps(self, thetas, dt, V, q):
        """Ad (S, m, 6, 6) and Γ (S, m, 6, q) of each sample at its own period and speed (where a decomposition
        is ill-conditioned): the hold's by scipy's expm of G·dt (as before issue 36), the others by the compiled
        Padé of :func:`~online_id.filters.sigma_block.sigma_expm_steps` at each sample's speed."""
        if q == 1:
            Ad, Bd = zip(*(discretise_continuous(*continuous_matrices(thetas, v, self.known), d)
                           for d, v in zip(dt, V)))
            return np.stack(Ad, axis=1), np.stack(Bd, axis=1)[..., None]
        S, m = len(thetas), len(dt)
        Ad, Gam = np.empty((S, m, N_STATES, N_STATES)), np.empty((S, m, N_STATES, q))
        one_A, one_G = np.empty((S, 1, N_STATES, N_STATES)), np.empty((S, 1, N_STATES, q))
        for k, (d, v) in enumerate(zip(dt, V)):
            G, dG = speed_generators(thetas, v, self.known)
            sigma_expm_steps(G, dG[:, None], np.array([d]), _NO_SPEED_CHANGE, 0.0, one_A, one_G)
            Ad[:, k], Gam[:, k] = one_A[:, 0], one_G[:, 0]
        return Ad, Gam

    def _propagate_sigmas(self, sigmas: np.ndarray) -> np.ndarray:
        """Advance every sigma point (rows) through the block; average each one's accepted outputs
        (the loop over samples and points is compiled, filters/sigma_block.py)."""
        out = sigmas.copy()
        S = len(sigmas)
        X = np.ascontiguousarray(sigmas[:, :N_STATES])
        thetas = self.theta0 * np.exp(sigmas[:, PARAMS])
        aug, e = self.augment, sigmas[:, N_AUG:]
        # augmentation: each point's steering shift (S,), output offset (S, 4) and output-matrix term
        shift = aug.steering_shift(e) if aug else np.zeros(S)
        y_offset = np.zeros((S, N_OUTPUTS))  # (a writable array: one compiled version)
        if aug:
            y_offset[:] = aug.output_offset(e)
        coupling = aug.output_matrix(e) if aug and aug.couples_state else None
        # a delay: each point's channels lag by its own τ, read at the mean's (filters/lagged.py): −Δτ·ẏ
        lagging = aug.lag_offset(e, self._kf.x[N_AUG:]) if aug and aug.has_lags else None
        lag = np.zeros((S, N_OUTPUTS)) if lagging is None else np.ascontiguousarray(lagging, dtype=float)
        sum_y = np.zeros((S, N_OUTPUTS))
        sum_z = np.zeros(N_OUTPUTS)
        n = np.zeros(N_OUTPUTS)
        rejected = np.zeros(N_OUTPUTS, dtype=np.int64)
        gate2 = self.config.gate_sigma ** 2
        R = np.asarray(self._R_now, dtype=float)
        dt, w, speed, delta_now, observed, values, mask = self._buffered()
        for i, j, V_ref in self._segments():
            Ad, Gam, rows, C, D, (rate_C, rate_D) = self._segment_steps(thetas, dt[i:j], speed[i:j], V_ref,
                                                                        lagging is not None)
            if coupling is not None:
                C = C + coupling
            sigma_pass(np.ascontiguousarray(Ad), np.ascontiguousarray(Gam), rows, X, w[i:j], delta_now[i:j],
                       observed[i:j], np.ascontiguousarray(values[i:j]), np.ascontiguousarray(mask[i:j]),
                       np.ascontiguousarray(C), np.ascontiguousarray(D), shift, y_offset, lag,
                       np.ascontiguousarray(rate_C), np.ascontiguousarray(rate_D), self._kf.Wm, self._kf.Wc, R, gate2,
                       sum_y, sum_z, n, rejected)
        if rejected.any():
            self.health.count_outlier_totals(rejected)
        return self._keep_propagated(out, X, sum_y, sum_z, n)

    def _keep_propagated(self, out, X, sum_y, sum_z, n):
        """What :meth:`_propagate_sigmas` leaves for the block's close: the points ``out`` with their model states
        ``X`` stepped through the block, the sums of the accepted outputs (``sum_y`` per point, ``sum_z``, the counts
        ``n``). Returns ``out``."""
        out[:, :N_STATES] = X
        self._block_sums = (sum_y, sum_z, n)
        self._propagated = out
        return out

    def _mend(self) -> None:
        """Drop the samples an interruption left half appended (Ctrl-C, SIGTERM or SIGHUP raise between any two
        steps of Python, e.g. between ``_propagate_observe_many``'s extends): every column cut to the samples whose
        every part is in."""
        columns = (self._dt, self._speed_held, self._delta_now, self._speed_now, self._observed)
        blocks = (self._w, self._values, self._masks)
        rows = [sum(len(b) for b in bl) for bl in blocks]
        m = min(min(len(c) for c in columns), min(rows))
        if all(len(c) == m for c in columns) and all(r == m for r in rows):
            return
        for c in columns:
            del c[m:]
        for bl in blocks:
            kept, total = [], 0
            for b in bl:
                if total >= m:
                    break
                kept.append(b[:m - total])
                total += len(kept[-1])
            bl[:] = kept

    def _flush(self):
        self._mend()
        if not self._dt:
            return
        elapsed = sum(self._dt)
        self._kf.Q = np.diag(self._process_noise(elapsed))
        self._kf.predict(dt=elapsed, fx=self._propagate_sigmas)
        self._dt, self._w, self._speed_held, self._delta_now, self._speed_now = [], [], [], [], []
        self._observed, self._values, self._masks = [], [], []

    def _block_innovation(self):
        if self._block_sums is None:
            return None
        sum_y, sum_z, n = self._block_sums
        self._block_sums = None
        channels = np.flatnonzero(n > 0)
        if channels.size == 0:
            return None
        kf = self._kf
        Ybar = sum_y[:, channels] / n[channels]
        z = sum_z[channels] / n[channels]
        R = np.diag(self._R_now[channels] / n[channels])
        zp, S = unscented_transform(Ybar, kf.Wm, kf.Wc, R)
        self._block = (channels, z, Ybar, R, zp, S)
        return channels, z, zp, S

    def _apply_correction(self, keep):
        kf = self._kf
        _, z, Ybar, R, zp, S = self._block
        if not keep.all():  # (every channel kept: the block's own transform)
            Ybar, z, R = Ybar[:, keep], z[keep], R[np.ix_(keep, keep)]
            zp, S = unscented_transform(Ybar, kf.Wm, kf.Wc, R)
        dx = self._propagated - kf.x
        dz = Ybar - zp
        Pxz = (kf.Wc[:, None] * dx).T @ dz
        K = Pxz @ np.linalg.inv(S)
        kf.x = kf.x + K @ (z - zp)
        P = kf.P - K @ S @ K.T
        kf.P = 0.5 * (P + P.T)
