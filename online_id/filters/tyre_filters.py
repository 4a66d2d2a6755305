"""The online filters with saturating tyres: μ estimated with the 8, the whole envelope learned from.

With ``tire_saturation`` among the extra states (:attr:`~online_id.filters.augment.Augmentation.has_tyres`)
the model is no longer linear in its state, and the linear filters' exact discretisation and grouped
propagation (filters/ekf.py, filters/local_model.py) do not apply. These variants predict with the model
of :mod:`online_id.model.tyres` (RK4 over each sample period, compiled), its steering the step's input curve
between the samples (``FilterConfig.intersample``, :mod:`online_id.model.intersample`: each RK4 stage takes
the curve's value at its own time, plus the extra states' steering shift), and keep everything else of
:class:`~online_id.filters.base.OnlineEstimator`: the guards, the block-mean corrections, the gating, the
consistency log.

EKF: each sample advances the mean through the nonlinear step and chains the step's exact Jacobian
(the local cornering stiffness D_i·sech²(u_i) where the step meets the tyre law; derivatives with respect
to the log-scale parameters, μ and the other extra states) into ∂x/∂z_block-start, so the block's
correction is the linear EKF's (filters/ekf.py's docstring: S = H̄ P H̄ᵀ + He Q Heᵀ + R, C = F P H̄ᵀ + Q Heᵀ,
Joseph's update), with H̄ the mean of each accepted sample's output sensitivity. The samples are worked
one by one (no groups): about 25 µs a sample for the step and the outputs.

UKF: every sigma point is advanced through the same nonlinear step
(:func:`online_id.model.tyres.step_points_input`) with its own parameters, μ and steering shift; the rest is
:class:`~online_id.filters.ukf.UKFEstimator`.

A delay (a lag among the extra states, :mod:`online_id.filters.lagged`) needs the outputs' rate ẏ: here the
backward difference of the predicted outputs between observed samples of a block (held over a correction,
where the mean jumps). It shapes only the gain (the mean is the model's own), so its half-sample lag costs
efficiency, not bias.

Where the model stops being valid: the tanh law cannot make more lateral force than μ1·Fz1 + μ2·Fz2 = μ̄·M·g
(μ̄ the axle-load-weighted mean; μ with one μ for both axles),
so a measured |a_y| beyond ``tyre_range``·(μ̄ + 3σ_μ)·g + 3σ_ay (``tyre_range`` default 1.25: the roll
acceleration adds to the tyres' share, :class:`~online_id.filters.config.FilterConfig`; μ's upper bound, so that
the samples that say μ̂ is too low are learned from; σ_ay the channel's measurement σ, whose noise rides on each
sample) is a car the law does not describe (a banked or bumpy
corner, a kerb, a spin): such samples are propagated
and not learned from, counted as ``outside_model_range``. The 0.5 g linear-range gate does not apply.
"""

from __future__ import annotations

import numpy as np

from online_id.effects.base import loads_with_speed
from online_id.filters.base import N_AUG, PARAMS, OnlineEstimator
from online_id.filters.block_update import block_covariances, joseph_update, observed_process_noise
from online_id.filters.tyre_block import sigma_tyre_pass, tyre_close, tyre_run
from online_id.filters.ukf import UKFEstimator
from online_id.model import tyres
from online_id.model.lateral import N_PARAMS, N_STATES
from online_id.stream.samples import MEASURED_CHANNELS
from online_id.units import G
from online_id.vehicle.parameters import axle_loads

N_OUT = len(MEASURED_CHANNELS)
_AY = MEASURED_CHANNELS.index("lateral_acceleration")
#: The tyre law's range is widened by this many of the a_y channel's noise σ (its measurement_std).
GATE_NOISE_SIGMAS = 3.0
_NO_OFFSET = np.zeros(5)  # (no extra states: tyre_run's output offsets and direct terms)
_NO_DIRECT = np.zeros((5, 0))
#: Where a run logs no longitudinal acceleration, the loads' a_x is dV/dt of the logged speed smoothed by a first-order
#: filter of this time constant [s] (causal: a live run has no later samples): a 100 Hz speed's raw difference has a
#: noise of metres a second squared; the pitch dynamics the loads follow take about this long.
AX_FROM_SPEED_TAU_S = 0.1


class _TyreModel:
    """The tyre model's constants for one estimator: known constants, axle loads, where μ and the steering
    shifts sit in the augmented state."""

    def __init__(self, known, augment, n_aug):
        self.kn = tyres.known_array(known)
        self.known = known
        self.Fz = axle_loads(known)
        #: the loads of the step into the sample being worked (the last sample's) and of its output (its own):
        #: static, unless the tyre law's loads follow a_x (Augmentation.moves_loads; :meth:`read`)
        self.Fz_step = self.Fz_out = self.Fz
        self._speed_at = None  # (t, V) of the last sample, and the smoothed dV/dt, where a_x is not logged
        self._ax_from_speed = 0.0
        self.augment = augment
        self._axle_loads = loads_with_speed(augment.axle_loads) if augment.axle_loads is not None else None
        idx = np.full(N_PARAMS + 2, -1, dtype=np.int64)
        idx[:N_PARAMS] = np.arange(N_STATES, N_AUG)
        for axle in range(2):
            if augment.tyre_mu[axle] >= 0:
                idx[N_PARAMS + axle] = N_AUG + augment.tyre_mu[axle]
        self.idx = idx
        self.scale = np.ones(N_PARAMS)
        steer = np.flatnonzero(augment.steering) if augment.n else np.zeros(0, dtype=np.int64)
        self.steer_cols = (N_AUG + steer).astype(np.int64)
        self.steer_g = augment.steering[steer].astype(float) if augment.n else np.zeros(0)
        self.n_aug = n_aug

    def read(self, sample) -> bool:
        """The axle loads of ``sample`` (its logged a_x, else dV/dt of the speed, :data:`AX_FROM_SPEED_TAU_S`), and
        of the step into it (the mean of the last sample's and this one's); whether its a_x came from the speed."""
        ax = sample.longitudinal_acceleration
        t, V = sample.time, sample.speed
        if self._speed_at is not None and t > self._speed_at[0] and V == V:
            h = t - self._speed_at[0]
            raw = (V - self._speed_at[1]) / h
            self._ax_from_speed += min(1.0, h / AX_FROM_SPEED_TAU_S) * (raw - self._ax_from_speed)
        if V == V and t == t:
            self._speed_at = (t, V)
        from_speed = ax is None or not ax == ax
        if from_speed:
            ax = self._ax_from_speed
        previous = self.Fz_out
        speed = V if V == V else (self._speed_at[1] if self._speed_at is not None else 0.0)
        self.Fz_out = np.ascontiguousarray(self._axle_loads(self.known, np.array([ax]), np.array([speed]))[0])
        # the step into this sample takes the two samples' mean (second order; the kernels' _step_loads)
        self.Fz_step = 0.5 * (previous + self.Fz_out) if previous.shape == self.Fz_out.shape else self.Fz_out
        return from_speed

    def mu(self, e) -> np.ndarray:
        return np.ascontiguousarray(self.augment.axle_mu(e))


class _ModelRange:
    """Learn from samples up to the tyre law's own limit (module docstring), not the linear range."""


    def _refresh_ay_limit(self) -> None:
        # μ's upper 3σ bound, not μ̂: samples beyond μ̂·g are what tells a low μ̂ to rise; gating at μ̂ would let a
        # μ̂ that fell lock itself in (seen on the race car: μ̂ 0.2, a third of the log unused, D 10× too high)
        e = self._extra_mean()
        sd = np.sqrt(np.clip(np.diag(self.P)[N_AUG:], 0.0, None))
        mu = self.augment.axle_mu(e + 3.0 * sd)
        Fz = self._tyre.Fz
        mu = float(np.sum(mu * Fz) / np.sum(Fz)) if np.all(np.isfinite(mu)) else float(np.min(mu[np.isfinite(mu)]))
        # a sample's own noise on top: the race car's a_y vibrates by 1 m/s² (σ), and at 1.25·μ̄·g alone the samples
        # of its hardest cornering, the ones that tell μ̄ is higher, were left out where μ̄ sat low
        noise = np.sqrt(self._R_nominal[_AY]) if np.isfinite(self._R_nominal[_AY]) else 0.0
        self._ay_limit = self.config.tyre_range * max(mu, tyres.MU_FLOOR) * G + GATE_NOISE_SIGMAS * noise
        self._ay_limit_event = "outside_model_range"


class _MovingLoads:
    """The tyre law's axle loads read sample by sample (filters/feeding.py calls :meth:`_read_loads` for each
    sample it works when an effect moves them, ``load_transfer``)."""

    def _read_loads(self, sample) -> None:
        if self._tyre.read(sample):  # (said: the events line counts the samples whose a_x came from the speed)
            self._events["longitudinal_acceleration_from_speed"] += 1


class TyreEKFEstimator(_MovingLoads, _ModelRange, OnlineEstimator):
    """Augmented-state EKF with saturating tyres (module docstring)."""

    name = "ekf"

    def _init_filter(self, x0, P0):
        self._x = x0.copy()
        self._P = P0.copy()
        self._tyre = _TyreModel(self.known, self.augment, len(x0))
        self._ydot = np.zeros(N_OUT)  # a delay's ẏ, held between blocks
        self._start_block()

    @property
    def x(self):
        return self._x

    @property
    def P(self):
        return self._P

    def _extra_mean(self):
        return self._x[N_AUG:]

    def _set(self, x, P):
        self._x = np.array(x, dtype=float)
        self._P = np.array(P, dtype=float)
        self._start_block()

    def _start_block(self):
        n = len(self._x)
        self._S = np.eye(N_STATES, n)  # ∂(model states now)/∂(augmented state at the block start)
        self._elapsed = 0.0
        self._P_start = None
        self._F_block = None
        self._sum_y = np.zeros(N_OUT)
        self._sum_z = np.zeros(N_OUT)
        self._sum_H = np.zeros((N_OUT, n))
        self._n = np.zeros(N_OUT)
        self._C_last = None
        self._gate_threshold = None
        self._block_samples = 0
        self._observed_at = []
        self._gap_at = None
        self._gap_variance = 0.0
        self._y_prev = None  # a delay's ẏ: the last observed sample's predicted outputs (module docstring)
        self._since_observed = 0.0
        self._constants()

    def _constants(self):
        """θ, μ and the steering shift at the current mean (they change only at corrections)."""
        x = self._x
        self._theta = self.theta0 * np.exp(x[PARAMS])
        e = x[N_AUG:]
        self._mu = self._tyre.mu(e)
        self._refresh_ay_limit()
        self._shift = float(self.augment.steering_shift(e)) if self.augment.n else 0.0

    def _propagate(self, dt, w, speed):
        t = self._tyre
        x, S = tyres.step_input(np.ascontiguousarray(self._x[:N_STATES]), self._S, self._theta, self._mu, t.Fz_step,
                                np.asarray(w, dtype=float), self._shift, speed, dt, t.kn, t.idx, t.scale,
                                t.steer_cols, t.steer_g)
        self._x[:N_STATES] = x
        self._S = S
        self._elapsed += dt
        self._since_observed += dt
        self._block_samples += 1

    def _observe(self, values, mask, delta, speed):
        t = self._tyre
        x = np.ascontiguousarray(self._x[:N_STATES])
        y, H, C = tyres.output(x, self._S, self._theta, self._mu, t.Fz_out, delta + self._shift, speed, t.kn, t.idx,
                               t.scale, t.steer_cols, t.steer_g)
        aug = self.augment
        if aug.n:
            e = self._x[N_AUG:]
            y = y + aug.output_offset(e)
            direct = aug.output
            if aug.couples_state:
                K = aug.output_matrix(e)
                y = y + K @ x
                C = C + K
                H = H + K @ self._S
                direct = direct + np.einsum("nij,j->in", aug.output_state, x)
            H[:, N_AUG:] += direct
            if aug.has_lags:
                H[:, N_AUG:] -= aug.lag * self._output_rate(y)[:, None]
        if self._gate_threshold is None:
            P = self._P
            self._gate_threshold = self.config.gate_sigma ** 2 * (((H @ P) * H).sum(axis=1) + self._R_now)
        values = np.asarray(values, dtype=float)
        r = values - y
        accept = mask & (r * r <= self._gate_threshold)
        rejected = mask & ~accept
        if rejected.any():
            self.health.count_outliers(rejected)
        if not accept.any():
            return
        if self._gap_at is None and np.any(self._gap_state_variance):
            self._gap_at = len(self._observed_at)
        self._observed_at.append(self._block_samples)
        w = accept.astype(float)
        self._sum_y += w * y
        self._sum_z += w * values
        self._sum_H += w[:, None] * H
        self._n += w
        self._C_last = C

    def _propagate_observe_many(self, dt, w, speed_step, values, mask, delta, speed, observe) -> None:
        """A run of the array path in one compiled call (:func:`online_id.filters.tyre_block.tyre_run`, the hooks'
        numbers): the samples up to the block's first observed one by the hooks (it sets the gate's threshold);
        extra states that couple to the model states, lag a channel or move the loads keep the hooks for every
        sample."""
        aug = self.augment
        if aug.n and (aug.couples_state or aug.has_lags or aug.moves_loads):  # (loads: read sample by sample)
            super()._propagate_observe_many(dt, w, speed_step, values, mask, delta, speed, observe)
            return
        k, m = 0, len(dt)
        while k < m and self._gate_threshold is None:
            self._propagate(dt[k], w[k], speed_step[k])
            if observe[k]:
                self._observe(values[k], mask, delta[k], speed[k])
            k += 1
        if k == m:
            return
        t = self._tyre
        e = self._x[N_AUG:]
        y_offset = np.asarray(aug.output_offset(e), dtype=float) if aug.n else _NO_OFFSET
        direct = np.ascontiguousarray(aug.output, dtype=float) if aug.n else _NO_DIRECT
        C_last = np.empty((N_OUT, N_STATES))
        accepted = np.empty(m - k, dtype=np.int64)
        rejected = np.zeros(N_OUT, dtype=np.int64)
        x, S, n_accepted = tyre_run(
            np.ascontiguousarray(self._x[:N_STATES]), self._S, self._theta, self._mu, t.Fz_step,
            np.ascontiguousarray(w[k:], dtype=float), self._shift, np.asarray(speed_step[k:], dtype=float),
            np.asarray(dt[k:], dtype=float), t.kn, t.idx, t.scale, t.steer_cols, t.steer_g,
            np.ascontiguousarray(values[k:], dtype=float), np.asarray(mask, dtype=np.bool_),
            np.asarray(delta[k:], dtype=float), np.asarray(speed[k:], dtype=float),
            np.asarray(observe[k:], dtype=np.bool_), y_offset, direct, self._gate_threshold, self._sum_y,
            self._sum_z, self._sum_H, self._n, C_last, accepted, rejected)
        self._x[:N_STATES] = x
        self._S = S
        for h in dt[k:]:  # (one by one: the hooks' sums of the periods, to the last bit)
            self._elapsed += h
            self._since_observed += h
        if rejected.any():
            self.health.count_outlier_totals(rejected)
        if n_accepted:
            if self._gap_at is None and np.any(self._gap_state_variance):
                self._gap_at = len(self._observed_at)
            self._observed_at.extend((self._block_samples + 1 + accepted[:n_accepted]).tolist())
            self._C_last = C_last
        self._block_samples += m - k

    def _output_rate(self, y) -> np.ndarray:
        """ẏ (5,) by the backward difference from the block's last observed sample, else the last one known."""
        if self._y_prev is not None and self._since_observed > 0:
            self._ydot = (y - self._y_prev) / self._since_observed
        self._y_prev, self._since_observed = y, 0.0
        return self._ydot

    def _close_block(self):
        """The block's close up to its correction in one compiled call (filters/tyre_block.py ``tyre_close``: the
        hooks' ``_flush``, ``_block_innovation``, the block's gate and ``joseph_update``, the same numbers), the
        correction applied; returns (channels, ν, diag S) for the health's one-call bookkeeping, or None with
        nothing done (a long gap in the block, nothing observed, a channel outside the block's gate, numbers that
        break down: the hooks then take it, as before)."""
        if (self._elapsed == 0.0 or self._P_start is not None or self._C_last is None or self._gap_at is not None
                or not (type(self._gap_state_variance) is float and self._gap_state_variance == 0.0)):
            return None
        observed_at = self._observed_at
        if not observed_at:
            return None
        walked = self._random_walk_variance
        q = self._process_noise(self._elapsed)
        share = sum(observed_at) / len(observed_at) / max(self._block_samples, 1)  # (observed_process_noise's)
        try:
            status, channels, z, zp, P_pred, K, P_new, S = tyre_close(
                self._S, self._P, q, share, self._sum_y, self._sum_z, self._sum_H, self._n, self._C_last,
                self._R_now, self.config.gate_sigma ** 2)
        except np.linalg.LinAlgError:  # (a singular S: the hooks' numpy says so as it did)
            status = 1
        if status:
            self._random_walk_variance = walked  # (the hooks' flush tallies it)
            return None
        nu = z - zp
        self._x = self._x + K @ nu
        self._P = P_new
        self._elapsed = 0.0
        return channels, nu, S.diagonal()

    def _flush(self):
        if self._elapsed == 0.0:
            return
        n = len(self._x)
        F = np.eye(n)
        F[:N_STATES] = self._S
        self._F_block = F
        self._gap_variance = self._gap_state_variance
        Q = self._process_noise(self._elapsed)
        self._q = Q
        self._P_start = self._P
        P = F @ self._P @ F.T + np.diag(Q)
        self._P = 0.5 * (P + P.T)
        self._elapsed = 0.0
        self._S = np.eye(N_STATES, n)

    def _block_innovation(self):
        n = self._n
        channels = np.flatnonzero(n > 0)
        if channels.size == 0 or self._P_start is None:
            return None
        z = self._sum_z[channels] / n[channels]
        zp = self._sum_y[channels] / n[channels]
        Hbar = self._sum_H[channels] / n[channels, None]
        q = observed_process_noise(self._q, self._gap_variance, self._gap_at, self._observed_at, self._block_samples)
        C, S = block_covariances(Hbar, self._C_last[channels], q, self._P_start, self._F_block,
                                 self._R_now[channels] / n[channels])
        self._block = (z, zp, C, S)
        return channels, z, zp, S

    def _apply_correction(self, keep):
        self._x, self._P = joseph_update(self._x, self._P, self._block, keep)
        # (θ, μ and the shift at the new mean: _start_block, which follows every correction, takes them)


class TyreUKFEstimator(_MovingLoads, _ModelRange, UKFEstimator):
    """Augmented-state UKF with saturating tyres: each sigma point through the nonlinear step."""

    name = "ukf"

    def _init_filter(self, x0, P0):
        self._tyre = _TyreModel(self.known, self.augment, len(x0))
        self._ydot = np.zeros(N_OUT)  # a delay's ẏ: the mean's, held between blocks; per point inside one
        super()._init_filter(x0, P0)

    def _extra_mean(self):
        return self._kf.x[N_AUG:]

    def _start_block(self):
        super()._start_block()
        self._loads: list[tuple] = []  # each buffered sample's (loads of its step, of its output)
        if hasattr(self, "_kf"):
            self._refresh_ay_limit()

    def _propagate(self, dt, w, speed):
        self._loads.append((self._tyre.Fz_step, self._tyre.Fz_out))  # (first: an interruption leaves it longer)
        super()._propagate(dt, w, speed)

    def _mend(self) -> None:
        super()._mend()
        del self._loads[len(self._dt):]

    def _flush(self):
        super()._flush()
        self._loads = []

    def _propagate_sigmas(self, sigmas: np.ndarray) -> np.ndarray:
        out = sigmas.copy()
        X = np.ascontiguousarray(out[:, :N_STATES])
        thetas = np.ascontiguousarray(self.theta0 * np.exp(sigmas[:, PARAMS]))
        aug, e = self.augment, sigmas[:, N_AUG:]
        shift = aug.steering_shift(e) if aug.n else np.zeros(len(sigmas))
        y_offset = aug.output_offset(e) if aug.n else 0.0
        coupling = aug.output_matrix(e) if aug.n and aug.couples_state else None
        # a delay: each point's channels lag by its own τ, read at the mean's; ẏ by backward differences
        lagging = aug.lag_offset(e, self._kf.x[N_AUG:]) if aug.n and aug.has_lags else None
        Y_prev, since = None, 0.0
        mus = self._tyre.mu(e)
        t = self._tyre
        Wm, Wc = self._kf.Wm, self._kf.Wc
        sum_y = np.zeros((len(sigmas), N_OUT))
        sum_z = np.zeros(N_OUT)
        n = np.zeros(N_OUT)
        gate2 = self.config.gate_sigma ** 2
        shift = np.ascontiguousarray(shift, dtype=float)
        loads = self._loads if self.augment.moves_loads else None
        if coupling is None and lagging is None and self._dt:  # the loop below in one compiled call, its numbers
            dt, w, V_step, delta_now, observed, values, masks = self._buffered()
            m = len(dt)
            if loads is None:
                Fz_step = Fz_out = np.broadcast_to(t.Fz, (m, 2))
            else:
                Fz_step = np.array([a for a, _ in loads[:m]], dtype=float)
                Fz_out = np.array([b for _, b in loads[:m]], dtype=float)
            rejected = np.zeros(N_OUT, dtype=np.int64)
            X = sigma_tyre_pass(X, thetas, mus, np.ascontiguousarray(Fz_step), np.ascontiguousarray(Fz_out), w,
                                shift, V_step, dt, t.kn, observed, np.ascontiguousarray(values),
                                np.ascontiguousarray(masks), delta_now, np.asarray(self._speed_now, dtype=float),
                                np.ascontiguousarray(np.broadcast_to(y_offset, (len(sigmas), N_OUT)), dtype=float),
                                Wm, Wc, np.asarray(self._R_now, dtype=float), gate2, sum_y, sum_z, n, rejected)
            if rejected.any():
                self.health.count_outlier_totals(rejected)
            return self._keep_propagated(out, X, sum_y, sum_z, n)
        for k, (dt, w, V, values, mask, delta_now, V_now) in enumerate(self._buffered_samples()):
            Fz_step, Fz_out = (t.Fz, t.Fz) if loads is None else loads[k]
            X = tyres.step_points_input(X, thetas, mus, Fz_step, w, shift, V, dt, t.kn)
            since += dt
            if mask is None:
                continue
            Y = tyres.output_points(X, thetas, mus, Fz_out, np.ascontiguousarray(delta_now + shift), V_now, t.kn)
            Y = Y + y_offset
            if coupling is not None:
                Y = Y + np.einsum("sij,sj->si", coupling, X)
            if lagging is not None:
                if Y_prev is not None:  # the block's first sample: the mean's rate from the last block
                    self._ydot = (Y - Y_prev) / since
                Y_prev, since = Y, 0.0
                Y = Y - lagging * self._ydot
            yp = Wm @ Y
            var = Wc @ (Y - yp) ** 2 + self._R_now
            accept = mask & ((values - yp) ** 2 <= gate2 * var)
            rejected = mask & ~accept
            if rejected.any():
                self.health.count_outliers(rejected)
            w = accept.astype(float)
            sum_y += Y * w
            sum_z += np.where(accept, values, 0.0)
            n += w
        if self._ydot.ndim == 2:
            self._ydot = Wm @ self._ydot  # held for the next block's first sample (its sigma points are new)
        return self._keep_propagated(out, X, sum_y, sum_z, n)


def __getattr__(name: str):
    """``TYRE_FILTERS``: the filters with saturating tyres by the name --filter takes, derived from the registry
    (online_id.filters.FILTERS, whose entries name the classes above)."""
    if name == "TYRE_FILTERS":
        from online_id.filters.registry import tyre_filters

        return tyre_filters()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
