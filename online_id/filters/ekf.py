"""Augmented-state extended Kalman filter on filterpy's :class:`ExtendedKalmanFilter`.

Prediction is nonlinear and exact for the mean: every sample the model states
advance through the zero-order-hold discretisation at the current parameters,
x ← Ad(θ, V) x + Bd(θ, V) δ. The Jacobian of one step with respect to the
augmented state z = [x, s] is

    F = [[Ad, ∂(Ad x + Bd δ)/∂s], [0, I]],   ∂/∂s_i = θ_i ∂/∂θ_i,

with ∂Ad/∂θ and ∂Bd/∂θ analytic (Van Loan). Within a block of k samples the
per-sample Jacobians are chained, F_j = F_j,1 ⋯ F_1 (from the block start), and
each sample's output sensitivity to the block-start state is H_j = [C F_xx,j,
C F_xs,j + ∂y/∂s]. The block correction uses the mean of the accepted samples,
ȳ, with H̄ = mean H_j mapped to the block-end state through F_k⁻¹ (the block's
process noise, 1e-10-level, is neglected in that cross term). The covariance is
propagated once per block: filterpy's ``predict`` with F = F_k and ``predict_x``
a no-op (the mean was already advanced), then filterpy's Joseph-form ``update``.

The discretisation is cached and rebuilt only when θ moved by more than
``relinearise_log_step`` (or V, dt changed); in between it is corrected to
first order in the change.
"""

from __future__ import annotations

import numpy as np
from filterpy.kalman import ExtendedKalmanFilter

from online_id.filters.base import N_AUG, OnlineEstimator
from online_id.model.discretise import Linearisation, linearise
from online_id.model.lateral import BETA, N_PARAMS, N_STATES

N_OUT = 4


class _MeanAlreadyPropagatedEKF(ExtendedKalmanFilter):
    """filterpy's EKF whose ``predict`` only propagates P: the mean is advanced sample by sample."""

    def predict_x(self, u=0):
        pass


class EKFEstimator(OnlineEstimator):
    """Augmented-state EKF. See :class:`~online_id.filters.base.OnlineEstimator` for the API."""

    name = "ekf"

    def _init_filter(self, x0, P0):
        self._kf = _MeanAlreadyPropagatedEKF(dim_x=N_AUG, dim_z=N_OUT)
        self._kf.x = x0.copy()
        self._kf.P = P0.copy()
        self._lin: Linearisation | None = None
        self._lin_s = None
        self._step = None
        self._step_key = (None, None)
        self._C_eff = self._D_eff = None
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
        self._step = None
        self._start_block()

    # -- block bookkeeping ----------------------------------------------------------------------------
    def _start_block(self):
        # ∂(model states now)/∂(augmented state at block start), (6, 14): [F_xx | F_xs]
        self._F_x = np.hstack([np.eye(N_STATES), np.zeros((N_STATES, N_PARAMS))])
        self._elapsed = 0.0
        self._flushed = None  # F_x of the block once its covariance was propagated
        self._n = np.zeros(N_OUT)
        self._sum_z = np.zeros(N_OUT)
        self._sum_y = np.zeros(N_OUT)
        self._sum_H = np.zeros((N_OUT, N_AUG))  # folded output sensitivities
        self._gate_var = None
        self._since_gate = 0
        self._clear_aggregates()

    def _clear_aggregates(self):
        """Running sums over the samples whose every channel was accepted, at one output matrix:
        Σ H_j = C Σ F_x,j, plus for a_y's θ-dependence V ∂β̇/∂s at Σ x_j and Σ δ_j."""
        self._agg_n = 0
        self._agg_mask = self._agg_w = None
        self._agg_F = np.zeros((N_STATES, N_AUG))
        self._agg_x = np.zeros(N_STATES)
        self._agg_delta = 0.0

    def _fold(self):
        """Turn the running sums into output sensitivities (before C changes, and at the block end)."""
        if self._agg_n:
            H = self._C_eff @ self._agg_F
            H[3, N_STATES:] += self._dAc_beta_s @ self._agg_x + self._dBc_beta_s * self._agg_delta
            self._sum_H += H * self._agg_w[:, None]
        self._clear_aggregates()

    # -- model at the current parameters --------------------------------------------------------------
    def _linearisation(self, speed: float, dt: float) -> Linearisation:
        """Cached linearisation; rebuilt when θ moved more than ``relinearise_log_step`` or V, dt changed."""
        s = self._kf.x[N_STATES:]
        lin = self._lin
        if (lin is None or np.abs(s - self._lin_s).max() > self.config.relinearise_log_step
                or abs(speed - lin.speed) > self.config.speed_tolerance * abs(lin.speed)
                or abs(dt - lin.dt) > 1e-3 * lin.dt):
            theta = self.theta0 * np.exp(s)
            lin = linearise(theta, speed, self.known, dt)
            self._lin, self._lin_s = lin, s.copy()
            # chain rule to log-scale: ∂/∂s_i = θ_i ∂/∂θ_i
            self._dAd_s = lin.dAd * theta[:, None, None]
            self._dBd_s = lin.dBd * theta[:, None]
            # J[i, k] = Σ_j ∂Ad[i, j]/∂s_k x_j as one (48, 6) matmul
            self._dAd_s_flat = self._dAd_s.transpose(1, 0, 2).reshape(N_STATES * N_PARAMS, N_STATES)
            self._dBd_s_T = self._dBd_s.T.copy()
            # ∂a_y/∂s_k = V (∂Ac[β]/∂s_k x + ∂Bc[β]/∂s_k δ)
            self._dAc_beta_s = lin.dAc[:, BETA, :] * theta[:, None] * lin.speed
            self._dBc_beta_s = lin.dBc[:, BETA] * theta * lin.speed
            self._step = None
        return lin

    def _step_matrices(self, speed: float, dt: float):
        """Ad, Bd at the current θ: the cached linearisation, corrected to first order in Δs."""
        V0, dt0 = self._step_key
        if (self._step is not None and abs(speed - V0) <= self.config.speed_tolerance * abs(V0)
                and abs(dt - dt0) <= 1e-3 * dt0):
            return self._step  # θ unchanged since (every change clears _step), same V and dt
        self._fold()  # the sums so far belong to the old output matrix
        lin = self._linearisation(speed, dt)
        self._step_key = (speed, dt)
        ds = self._kf.x[N_STATES:] - self._lin_s
        self._step = (lin.Ad + np.tensordot(ds, self._dAd_s, axes=1), lin.Bd + ds @ self._dBd_s, ds)
        # outputs at the current θ: a_y's row corrected to first order in the move since linearising
        self._C_eff = lin.C.copy()
        self._C_eff[3] += ds @ self._dAc_beta_s
        self._D_eff = lin.D.copy()
        self._D_eff[3] += ds @ self._dBc_beta_s
        return self._step

    # -- hooks ----------------------------------------------------------------------------------------
    def _propagate(self, dt, delta, speed):
        Ad, Bd, _ = self._step_matrices(speed, dt)
        x = self._kf.x[:N_STATES]
        J = (self._dAd_s_flat @ x).reshape(N_STATES, N_PARAMS) + self._dBd_s_T * delta
        self._kf.x[:N_STATES] = Ad @ x + Bd * delta
        F_x = Ad @ self._F_x
        F_x[:, N_STATES:] += J
        self._F_x = F_x
        self._elapsed += dt

    def _sample_sensitivity(self, x, delta):
        """This sample's output sensitivity to the block-start augmented state, (4, 14)."""
        H = self._C_eff @ self._F_x
        H[3, N_STATES:] += self._dAc_beta_s @ x + self._dBc_beta_s * delta
        return H

    def _observe(self, values, mask, delta, speed):
        x = self._kf.x[:N_STATES]
        y = self._C_eff @ x + self._D_eff * delta
        # gate each channel against its predicted spread (block-start covariance), refreshed
        # every 5 samples: the spread grows slowly within a block
        if self._gate_var is None or self._since_gate >= 5:
            H = self._sample_sensitivity(x, delta)
            self._gate_threshold = self.config.gate_sigma ** 2 * (((H @ self._kf.P) * H).sum(axis=1) + self._R_diag)
            self._gate_var = True
            self._since_gate = 0
        self._since_gate += 1
        d = values - y
        ok = d * d <= self._gate_threshold
        if ok.all() or (ok | ~mask).all():  # every usable channel accepted: the cheap path
            if self._agg_n and not (mask == self._agg_mask).all():
                self._fold()
            if not self._agg_n:
                self._agg_mask = mask.copy()
                self._agg_w = mask.astype(float)
            self._sum_z += values  # unusable channels carry 0.0
            self._sum_y += y * self._agg_w
            self._n += self._agg_w
            self._agg_n += 1
            self._agg_F += self._F_x
            self._agg_x += x
            self._agg_delta += delta
            return
        accept = mask & ok
        rejected = mask & ~accept
        if rejected.any():
            self._count_outliers(rejected)
        if accept.any():
            w = accept.astype(float)
            self._sum_z += values * w
            self._sum_y += y * w
            self._sum_H += self._sample_sensitivity(x, delta) * w[:, None]
            self._n += w

    def _flush(self):
        if self._elapsed == 0.0:
            return
        F = np.eye(N_AUG)
        F[:N_STATES] = self._F_x
        self._kf.F = F
        self._kf.Q = np.diag(self._process_noise(self._elapsed))
        self._kf.predict()
        self._flushed = self._F_x
        self._elapsed = 0.0

    def _block_innovation(self):
        self._fold()
        channels = np.flatnonzero(self._n > 0)
        if channels.size == 0 or self._flushed is None:
            return None
        n = self._n[channels]
        z = self._sum_z[channels] / n
        zp = self._sum_y[channels] / n
        Hbar = self._sum_H[channels] / n[:, None]
        # H̄ refers to the block-start state; map to the block end: z_end = F z_start
        F_xx, F_xs = self._flushed[:, :N_STATES], self._flushed[:, N_STATES:]
        H = np.empty_like(Hbar)
        H[:, :N_STATES] = np.linalg.solve(F_xx.T, Hbar[:, :N_STATES].T).T
        H[:, N_STATES:] = Hbar[:, N_STATES:] - H[:, :N_STATES] @ F_xs
        R = np.diag(self._R_diag[channels] / n)
        S = H @ self._kf.P @ H.T + R
        self._block = (channels, z, zp, H, R)
        return channels, z, zp, S

    def _apply_correction(self, keep):
        _, z, zp, H, R = self._block
        H, z, zp, R = H[keep], z[keep], zp[keep], R[np.ix_(keep, keep)]
        self._kf.update(z, HJacobian=lambda _x: H, Hx=lambda _x: zp, R=R)
        self._kf.P = 0.5 * (self._kf.P + self._kf.P.T)
        self._step = None
