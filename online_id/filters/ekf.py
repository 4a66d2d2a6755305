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

Samples are worked in groups. The parameters only change at corrections, so
between two step changes Ad, Bd and C are constant and the mean, the chained
Jacobians and the outputs of a group of samples are a few matrix products:
with the block-Toeplitz matrix T of powers of Ad (T[a, b] = Ad^(a-b), a ≥ b),

    x_1..m = [Ad; …; Ad^m] x_0 + T (Bd δ_1, …, Bd δ_m),
    F_x,1..m = [Ad; …; Ad^m] F_x,0 + [0 | T (J_1, …, J_m)],   J_j = ∂(Ad x_j-1 + Bd δ_j)/∂s,

instead of a Python loop of small products per sample. A group ends every
``GATE_REFRESH`` samples (where the gate threshold is refreshed), at a step
change, at a correction, or when the model states are read (:attr:`x`), so the
result does not depend on when it is looked at.

Extra states e (offsets, effect parameters; :mod:`online_id.filters.augment`) follow the
parameters in z. They change only at corrections, so within a group the road-wheel angle
δ + g·e, the output offset M e and the output matrix C + Σ e_i K_i are constant; e's columns of
the chained Jacobian are T (Bd g) summed over the group, and its direct output sensitivity
D gᵀ + M + [K_i x] is added where the samples' sensitivities are summed.
"""

from __future__ import annotations

import numpy as np
from filterpy.kalman import ExtendedKalmanFilter
from scipy.linalg.lapack import dgesv

from online_id.filters.base import N_AUG, PARAMS, OnlineEstimator
from online_id.model.discretise import Linearisation, linearise
from online_id.model.lateral import BETA, N_PARAMS, N_STATES

N_OUT = 4

_ALL_CHANNELS = np.arange(N_OUT)


def _solve(a, b):
    """a⁻¹ b by LAPACK's gesv (numpy's solve costs 4x more at this size)."""
    _, _, x, info = dgesv(a, b)
    if info != 0:
        raise np.linalg.LinAlgError(f"singular block transition (gesv info {info})")
    return x


#: Samples between refreshes of each channel's gate threshold, and the largest group worked at
#: once (one block at the default correct_every of 20). Measured on the built-in run, a channel's
#: predicted spread at a block's 20th sample is its spread at the first to a median of 1.00x
#: (extremes 0.78x-1.43x), and no clean sample is rejected against a 5σ gate.
GATE_REFRESH = 20


class _MeanAlreadyPropagatedEKF(ExtendedKalmanFilter):
    """filterpy's EKF whose ``predict`` only propagates P: the mean is advanced sample by sample."""

    def predict_x(self, u=0):
        pass


class EKFEstimator(OnlineEstimator):
    """Augmented-state EKF. See :class:`~online_id.filters.base.OnlineEstimator` for the API."""

    name = "ekf"

    def _init_filter(self, x0, P0):
        self._kf = _MeanAlreadyPropagatedEKF(dim_x=self.n_aug, dim_z=N_OUT)
        self._kf.x = x0.copy()
        self._kf.P = P0.copy()
        self._lin: Linearisation | None = None
        self._lin_s = None
        self._step = None
        self._step_key = (None, None)
        self._C_eff = self._D_eff = None
        self._group_size = 0
        self._F_block = np.eye(self.n_aug)  # F of a block, rows of the model states rewritten each flush
        self._delta_shift, self._y_offset = 0.0, np.zeros(N_OUT)  # augmentation: g·e and M e at the current e
        # T's block (a, b) takes power a - b of Ad, or the zero matrix (index 0) above the diagonal
        a = np.arange(GATE_REFRESH)
        self._toeplitz_index = np.where(a[:, None] >= a[None, :], a[:, None] - a[None, :] + 1, 0)
        self._pending_delta: list[float] = []
        self._pending_obs: list[tuple] = []
        self._any_unconfigured = not self._configured.all()
        self._start_block()

    @property
    def x(self):
        self._catch_up()
        return self._kf.x

    @property
    def P(self):
        return self._kf.P

    def _parameter_mean(self):
        return self._kf.x[PARAMS]

    def _sync(self):
        self._catch_up()

    def _set(self, x, P):
        self._pending_delta.clear()
        self._pending_obs.clear()
        self._kf.x = x
        self._kf.P = P
        self._step = None
        self._start_block()

    # -- block bookkeeping ----------------------------------------------------------------------------
    def _start_block(self):
        # ∂(model states now)/∂(augmented state at block start), (6, 14): [F_xx | F_xs]
        self._F_x = np.eye(N_STATES, self.n_aug)
        self._elapsed = 0.0
        self._flushed = None  # F_x of the block once its covariance was propagated
        self._n = np.zeros(N_OUT)
        self._sum_z = np.zeros(N_OUT)
        self._sum_y = np.zeros(N_OUT)
        self._sum_H = np.zeros((N_OUT, self.n_aug))  # folded output sensitivities
        self._gate_threshold = None
        self._since_gate = GATE_REFRESH  # the first sample of a block refreshes the gate
        self._refresh_gate = False  # the pending group starts with a gate refresh
        self._clear_aggregates()

    def _clear_aggregates(self):
        """Running sums over the samples whose every channel was accepted, at one output matrix:
        Σ H_j = C Σ F_x,j, plus for a_y's θ-dependence V ∂β̇/∂s at Σ x_j and Σ δ_j (Σ z_j goes
        straight into the block's sums)."""
        self._agg_n = 0
        self._agg_mask = self._agg_w = None
        self._agg_F = np.zeros((N_STATES, self.n_aug))
        self._agg_x = np.zeros(N_STATES)
        self._agg_delta = 0.0

    def _fold(self):
        """Turn the running sums into output sensitivities, predicted outputs and counts (before C
        changes, and at the block end): Σ y_j = C Σ x_j + D Σ δ_j over the aggregated samples."""
        if self._agg_n:
            w = self._agg_w
            H = self._C_eff @ self._agg_F
            H[3, PARAMS] += self._dAc_beta_s @ self._agg_x + self._dBc_beta_s * self._agg_delta
            if self.augment:  # the extra states' direct sensitivity
                H[:, N_AUG:] += self.augment.sensitivity(self._D_eff, self._agg_x, self._agg_n)
            self._sum_H += H * w[:, None]
            self._sum_y += (self._C_eff @ self._agg_x + self._D_eff * self._agg_delta
                            + self._y_offset * self._agg_n) * w
            self._n += self._agg_n * w
        self._clear_aggregates()

    # -- model at the current parameters --------------------------------------------------------------
    def _linearisation(self, speed: float, dt: float) -> Linearisation:
        """Cached linearisation; rebuilt when θ moved more than ``relinearise_log_step`` or V, dt changed."""
        s = self._kf.x[PARAMS]
        lin = self._lin
        if (lin is None or np.abs(s - self._lin_s).max() > self.config.relinearise_log_step
                or abs(speed - lin.speed) > self.config.speed_tolerance * abs(lin.speed)
                or abs(dt - lin.dt) > 1e-3 * lin.dt):
            theta = self.theta0 * np.exp(s)
            lin = linearise(theta, speed, self.known, dt)
            self._lin, self._lin_s = lin, s.copy()
            # chain rule to log-scale: ∂/∂s_i = θ_i ∂/∂θ_i
            dAd_s = lin.dAd * theta[:, None, None]
            self._dAd_s_rows = dAd_s.reshape(N_PARAMS, N_STATES * N_STATES)
            self._dBd_s = lin.dBd * theta[:, None]
            # J[i, k] = Σ_j ∂Ad[i, j]/∂s_k x_j for a stack of x as one (m, 6) @ (6, 48) product
            self._dAd_s_flat_T = dAd_s.transpose(1, 0, 2).reshape(N_STATES * N_PARAMS, N_STATES).T.copy()
            self._dBd_s_T = self._dBd_s.T.copy()
            # ∂a_y/∂s_k = V (∂Ac[β]/∂s_k x + ∂Bc[β]/∂s_k δ)
            self._dAc_beta_s = lin.dAc[:, BETA, :] * theta[:, None] * lin.speed
            self._dBc_beta_s = lin.dBc[:, BETA] * theta * lin.speed
            self._step = None
        return lin

    def _step_matrices(self, speed: float, dt: float) -> None:
        """Ad, Bd at the current θ (the cached linearisation corrected to first order in Δs), and the
        outputs C, D likewise."""
        self._fold()  # the sums so far belong to the old output matrix
        lin = self._linearisation(speed, dt)
        self._step_key = (speed, dt)
        ds = self._kf.x[PARAMS] - self._lin_s
        Ad = lin.Ad + (ds @ self._dAd_s_rows).reshape(N_STATES, N_STATES)
        Bd = lin.Bd + ds @ self._dBd_s
        # outputs at the current θ: a_y's row corrected to first order in the move since linearising
        self._C_eff = lin.C.copy()
        self._C_eff[3] += ds @ self._dAc_beta_s
        self._D_eff = lin.D.copy()
        self._D_eff[3] += ds @ self._dBc_beta_s
        if self.augment:  # constant until the next correction, which rebuilds the step
            e = self._kf.x[N_AUG:]
            self._delta_shift = float(self.augment.steering_shift(e))
            self._y_offset = self.augment.output_offset(e)
            self._C_eff += self.augment.output_matrix(e)
        self._group_size = 0  # the group matrices are built when a group needs them
        self._step = (Ad, Bd)

    def _group_matrices(self, m: int) -> None:
        """Powers of Ad stacked (A), the block-Toeplitz T and T_B for groups of up to m samples, at the
        current step. Sized to the group: a log whose sample period jitters changes step at nearly
        every sample, and its groups of one need no powers at all."""
        Ad, Bd = self._step
        # Ad^1..Ad^m by doubling: [Ad^(k+1), …, Ad^(2k)] = Ad^k [Ad, …, Ad^k]
        powers = np.empty((m + 1, N_STATES, N_STATES))  # I, Ad, Ad², …
        powers[0] = np.eye(N_STATES)
        powers[1] = Ad
        k = 1
        while k < m:
            j = min(k, m - k)
            np.matmul(powers[k], powers[1:j + 1], out=powers[k + 1:k + j + 1])
            k += j
        self._powers = powers[1:].reshape(m * N_STATES, N_STATES)  # Ad, Ad², … stacked
        blocks = np.concatenate([np.zeros((1, N_STATES, N_STATES)), powers[:-1]])  # 0, I, Ad, …
        m6 = m * N_STATES
        self._T = blocks[self._toeplitz_index[:m, :m]].transpose(0, 2, 1, 3).reshape(m6, m6)
        # the mean's response to the group's inputs: column i holds Ad^(a-i) Bd in block row a
        self._T_B = self._T.reshape(m6, m, N_STATES) @ Bd
        self._group_size = m

    # -- hooks ----------------------------------------------------------------------------------------
    def _propagate(self, dt, delta, speed):
        V0, dt0 = self._step_key
        if (self._step is None or abs(speed - V0) > self.config.speed_tolerance * abs(V0)
                or abs(dt - dt0) > 1e-3 * dt0):
            self._catch_up()  # the pending samples belong to the old step
            self._step_matrices(speed, dt)
        if self._since_gate >= GATE_REFRESH:  # so no group grows past GATE_REFRESH samples
            self._catch_up()
            self._refresh_gate = True
            self._since_gate = 0
        self._since_gate += 1
        self._pending_delta.append(delta + self._delta_shift)  # the road-wheel angle the car sees
        self._elapsed += dt

    def _observe(self, values, mask, delta, speed):
        self._pending_obs.append((len(self._pending_delta), values, mask, delta + self._delta_shift))

    def _catch_up(self):
        """Work the pending samples as one group: mean, chained Jacobians, gating, block sums."""
        m = len(self._pending_delta)
        if not m:
            return
        d = np.array(self._pending_delta)
        self._pending_delta.clear()
        if m > self._group_size:
            self._group_matrices(m)
        m6 = m * N_STATES
        T = self._T[:m6, :m6]
        A = self._powers[:m6]
        x0 = self._kf.x[:N_STATES]
        X = np.empty((m + 1, N_STATES))  # X[j]: model states after j samples of the group
        X[0] = x0
        X[1:] = (A @ x0 + self._T_B[:m6, :m] @ d).reshape(m, N_STATES)
        J = (X[:-1] @ self._dAd_s_flat_T).reshape(m6, N_PARAMS)  # J_j from x_j-1 and δ_j, stacked
        J += (d[:, None, None] * self._dBd_s_T).reshape(m6, N_PARAMS)
        F = np.empty((m + 1, N_STATES, self.n_aug))
        F[0] = self._F_x
        Fg = F[1:].reshape(m6, self.n_aug)
        Fg[:] = A @ self._F_x
        Fg[:, PARAMS] += T @ J
        if self.augment:  # e moves every sample's input by g·e: its response is T (Bd g)
            Fg[:, N_AUG:] += np.outer(self._T_B[:m6, :m].sum(axis=1), self.augment.steering)
        self._kf.x[:N_STATES] = X[m]
        self._F_x = F[m].copy()
        if self._refresh_gate:
            self._refresh_gate = False
            obs = self._pending_obs
            delta = obs[0][3] if obs and obs[0][0] == 1 else d[0]
            H = self._sample_sensitivity(X[1], delta, F[1])
            self._gate_threshold = self.config.gate_sigma ** 2 * (((H @ self._kf.P) * H).sum(axis=1) + self._R_diag)
        if self._pending_obs:
            self._absorb(self._pending_obs, X, F)
            self._pending_obs = []

    def _sample_sensitivity(self, x, delta, F_x):
        """A sample's output sensitivity to the block-start augmented state, (4, 14)."""
        H = self._C_eff @ F_x
        H[3, PARAMS] += self._dAc_beta_s @ x + self._dBc_beta_s * delta
        if self.augment:
            H[:, N_AUG:] += self.augment.sensitivity(self._D_eff, x, 1)
        return H

    def _absorb(self, obs, X, F):
        """Gate the group's observations against the threshold and add them to the block."""
        configured = self._configured
        if len(obs) == len(X) - 1:  # every sample of the group observed (the usual case)
            Xo, Fo = X[1:], F[1:]
            idx = range(1, len(X))
        else:
            idx = [o[0] for o in obs]
            Xo, Fo = X[idx], F[idx]
        values = np.array([o[1] for o in obs], dtype=float)
        deltas = np.array([o[3] for o in obs])
        Y = Xo @ self._C_eff.T + deltas[:, None] * self._D_eff + self._y_offset
        r = values - Y
        ok = r * r <= self._gate_threshold
        complete = all(o[2] is configured for o in obs)  # all channels there: one shared mask
        if complete and self._any_unconfigured:
            ok |= ~configured
        if complete and ok.all():  # every usable channel accepted under one mask: the cheap path
            # (the values of unconfigured channels are summed too; channels without samples are not read)
            self._aggregate(configured, values.sum(axis=0), len(obs), Fo.sum(axis=0), Xo.sum(axis=0),
                            deltas.sum())
            return
        if not complete:
            ok |= ~np.array([o[2] for o in obs])
        for i, j in enumerate(idx):  # a rejection or a change of usable channels: sample by sample
            self._absorb_one(values[i], obs[i][2], deltas[i], X[j], F[j], Y[i], ok[i])

    def _aggregate(self, mask, sum_z, count, sum_F, sum_x, sum_delta):
        """Add ``count`` samples whose every usable channel (``mask``) was accepted to the running sums;
        a different mask first folds the sums so far."""
        if self._agg_n and not (mask is self._agg_mask or (mask == self._agg_mask).all()):
            self._fold()
        if not self._agg_n:
            self._agg_mask = mask
            self._agg_w = mask.astype(float)
        self._sum_z += sum_z
        self._agg_n += count
        self._agg_F += sum_F
        self._agg_x += sum_x
        self._agg_delta += sum_delta

    def _absorb_one(self, values, mask, delta, x, F_x, y, ok):
        if ok.all():
            self._aggregate(mask, np.where(mask, values, 0.0), 1, F_x, x, delta)
            return
        accept = mask & ok
        rejected = mask & ~accept
        if rejected.any():
            self._count_outliers(rejected)
        if accept.any():
            w = accept.astype(float)
            self._sum_z += values * w
            self._sum_y += y * w
            self._sum_H += self._sample_sensitivity(x, delta, F_x) * w[:, None]
            self._n += w

    def _flush(self):
        self._catch_up()
        if self._elapsed == 0.0:
            return
        F = self._F_block
        F[:N_STATES] = self._F_x
        self._kf.F = F
        self._kf.Q = np.diag(self._process_noise(self._elapsed))
        self._kf.predict()
        self._flushed = self._F_x
        self._elapsed = 0.0

    def _block_innovation(self):
        self._fold()
        n = self._n
        if n.all():  # every channel has samples (the usual case): no selection
            channels = _ALL_CHANNELS
            sum_z, sum_y, sum_H = self._sum_z, self._sum_y, self._sum_H
        else:
            channels = np.flatnonzero(n > 0)
            if channels.size == 0:
                return None
            n, sum_z, sum_y, sum_H = n[channels], self._sum_z[channels], self._sum_y[channels], self._sum_H[channels]
        if self._flushed is None:
            return None
        z = sum_z / n
        zp = sum_y / n
        Hbar = sum_H / n[:, None]
        # H̄ refers to the block-start state; map to the block end: z_end = F z_start
        F_xx, F_xs = self._flushed[:, :N_STATES], self._flushed[:, N_STATES:]
        H = np.empty_like(Hbar)
        H[:, :N_STATES] = _solve(F_xx.T, Hbar[:, :N_STATES].T).T
        H[:, N_STATES:] = Hbar[:, N_STATES:] - H[:, :N_STATES] @ F_xs
        R = np.diag(self._R_diag[channels] / n)
        S = H @ self._kf.P @ H.T + R
        self._block = (channels, z, zp, H, R)
        return channels, z, zp, S

    def _apply_correction(self, keep):
        _, z, zp, H, R = self._block
        if not keep.all():
            H, z, zp, R = H[keep], z[keep], zp[keep], R[np.ix_(keep, keep)]
        self._kf.update(z, HJacobian=lambda _x: H, Hx=lambda _x: zp, R=R)
        P = self._kf.P
        self._kf.P = 0.5 * (P + P.T)
        self._step = None
