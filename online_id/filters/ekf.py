"""Augmented-state extended Kalman filter on filterpy's :class:`ExtendedKalmanFilter`.

Predict. Every sample the model states advance through the exact step at the current parameters driven
by the step's input between its two samples, w = [δ(0), δ'(0), δ''(0), δ'''(0)] in normalised time
(:mod:`online_id.model.intersample`; ``FilterConfig.intersample``),

    x ← Ad x + Γ w,   Γ = [Γ_0 … Γ_3] (6, 4),  Γ_k = [φ_k(G T)]_{0:6, 6},  Γ_0 = Bd,

exact for the mean (the hold's w = [δ, 0, 0, 0] gives the zero-order hold, Bd δ, and is worked with Γ_0 alone:
its numbers are those before issue 36, bit for bit), and the Jacobian of the augmented state z = [x, s]
chains from the block start:

    F_j = [[Ad_j, ∂(Ad_j x + Γ_j w_j)/∂s], [0, I]] F_j-1,   ∂/∂s_i = θ_i ∂/∂θ_i.

The covariance is propagated once per block with the chained F (filterpy's ``predict``, whose
``predict_x`` is a no-op here: the mean was already advanced).

Update. Each block of ``correct_every`` samples ends with one correction from the block means of the
accepted samples (filters/base.py): ȳ = H̄ z_start + v with H̄ the mean of each sample's output
sensitivity to the block-start state, so (P_start the covariance before the block's predict)

    S = H̄ P_start H̄ᵀ + R,   C = cov(z_end, ȳ) = F P_start H̄ᵀ,   K = C S⁻¹,
    z_end ← z_end + K (ȳ − ŷ),   P ← P − K Cᵀ − C Kᵀ + K S Kᵀ   (Joseph's form: right for any K).

The block's process noise Q builds up over its m samples, so its j-th sample sees about j/m of it (a long
gap's state variance, sample_gaps.py, is seen by the samples after the gap). S and C add the observed
samples' mean share w of Q ((m + 1)/(2m) when every sample is observed),
through the outputs' sensitivity H_e to the block-end state (C for the model states, H̄'s for the
parameters): exact for one sample per block (w = 1, the reference test's filter), a Q-sized term at 20.

No F⁻¹: at 100 Hz a block lasts 0.2 s, in which the tyre lags (V/b up to ~200 /s) decay by e⁻⁴⁰, so F is
singular to round-off there; mapping H̄ to the block end through F⁻¹ made S ill-conditioned (rcond
1e-20) and reset the filter on the race-car log.

Where the speed lives (each piece is a small module with its own tests; ``tests/test_filters_reference.py``
compares this class with a plain per-sample filterpy EKF):

* :mod:`~online_id.filters.local_model`: the steps Ad_j, Γ_j and their parameter columns for any
  sample period and for speeds within ``speed_tolerance`` of a linearisation point, from one
  eigen-decomposition (first order in speed and parameters, exact in dt; error bounds there);
* :mod:`~online_id.filters.groups`: a group of pending samples in two matrix products (the mean and
  the chained Jacobians), however speed and period vary inside it; when the speed leaves one
  linearisation point's range inside a group, the group goes on with the next point's steps;
* :mod:`~online_id.filters.spectral_group`: a group whose sample period changes at every sample (a CAN
  log's jitter, where no per-period tables apply), the same arithmetic in one compiled loop;
* :mod:`~online_id.filters.block_sums`: the block's running sums.

A group ends every ``GATE_REFRESH`` observed samples (where each channel's gate threshold is
refreshed; samples bridged across a gap or not learned from do not count) or ``MAX_GROUP`` samples, when
the parameters move (a new linearisation point), at a correction, or when the model states are read
(:attr:`x`), so the result does not depend on when it is looked at.

Extra states e (offsets, effect parameters; :mod:`online_id.filters.augment`) follow the parameters in
z and change only at corrections, so between two the road-wheel angle δ + g·e and the outputs
(C + Σ e_i K_i) x + D δ + M e are fixed (``_delta_shift``; :meth:`LinearOutputs.with_extra_states`). The
shift is constant over a step: it moves the step input's value w_0 only, so their step columns are
Γ_0,j gᵀ = Bd_j gᵀ, chained with the parameters'; their direct output sensitivity
D gᵀ + M + [K_i x] is added with the parameters' (filters/local_model.py), and a delay's −ẏ on the channels
it lags (filters/lagged.py; ẏ from C·A and C·B at the linearisation point).
"""

from __future__ import annotations

import numpy as np

from online_id.filters import block_close
from online_id.filters._filterpy import ExtendedKalmanFilter
from online_id.filters.base import N_AUG, PARAMS, OnlineEstimator
from online_id.filters.block_close import predict_covariance
from online_id.filters.block_sums import BlockSums
from online_id.filters.block_update import block_covariances, joseph_update, observed_process_noise
from online_id.filters.groups import chain_jacobians, propagate_mean, recurse_group, transition_table
from online_id.filters.local_model import LocalModel, _TableGroupSteps, compile_now, local_model, one_period
from online_id.filters.spectral_group import propagate_group
from online_id.model.intersample import ORDER
from online_id.model.lateral import N_STATES
from online_id.stream.samples import MEASURED_CHANNELS

N_OUT = len(MEASURED_CHANNELS)
_NO_STEERING = np.zeros(0)
#: The hold's (empty) input-polynomial table for block_close.close_block.
_NO_INPUTS = np.zeros(0)

#: Samples between refreshes of each channel's gate threshold, and the largest group worked at
#: once (one block at the default correct_every of 20). Measured on the built-in run, a channel's
#: predicted spread at a block's 20th sample is its spread at the first to a median of 1.00x
#: (extremes 0.78x-1.43x), and no clean sample is rejected against a 5σ gate.
GATE_REFRESH = 20
#: The largest group: samples that are propagated but not observed (bridged across lost samples,
#: outside the linear range) do not refresh the gate, so a group may hold more than GATE_REFRESH.
MAX_GROUP = 2 * GATE_REFRESH


def _stacked(arrays):
    """The arrays joined along the first axis, without a copy for one array (a group at one point)."""
    return arrays[0] if len(arrays) == 1 else np.concatenate(arrays)


def _spans(runs, m):
    """(first, end, LocalModel) of each run of a group of m samples, from its (first sample's index, model)."""
    ends = [start for start, _ in runs[1:]] + [m]
    return [(a, b, model) for (a, model), b in zip(runs, ends)]


def _zero(v) -> bool:
    """Whether a variance (0.0, or an array after a long gap) is all zero (``not np.any(v)``, without numpy for
    a float)."""
    return v == 0.0 if type(v) is float else not np.any(v)


class _MeanAlreadyPropagatedEKF(ExtendedKalmanFilter):
    """filterpy's EKF whose ``predict`` only propagates P: the mean is advanced sample by sample."""

    def predict_x(self, u=0):
        pass


class _Pending:
    """Samples propagated but not yet worked: per sample the period, the step's input (its value w_0 with the
    extra states' steering shift in ``delta``; its derivatives w_1 … in ``slopes``, an input polynomial's
    only, as blocks of rows), and V; the observations as (sample number in the group, 1-based; values; usable
    mask; δ at the sample); and the runs of samples each linearisation point covers, as (first sample's index,
    LocalModel): the speed may leave one point's range inside a group without ending it."""

    def __init__(self):
        self.dt: list[float] = []
        self.delta: list[float] = []
        self.slopes: list = []
        self.speed: list[float] = []
        self.observations: list[tuple] = []
        self.runs: list[tuple] = []

    def __len__(self):
        return len(self.dt)

    def clear(self):
        """Start a new group (new lists: the worked group's may still be read)."""
        self.dt, self.delta, self.slopes, self.speed, self.observations, self.runs = [], [], [], [], [], []

    def mend(self, order: int) -> None:
        """Drop the samples an interruption left half appended (Ctrl-C, SIGTERM or SIGHUP raise between any two
        steps of Python: the periods may be in and the speeds not yet): every list cut to the samples whose every
        part is in. A no-op on a whole group."""
        rows = sum(len(block) for block in self.slopes) if order > 1 else len(self.dt)
        m = min(len(self.dt), len(self.delta), len(self.speed), rows)
        if m == len(self.dt) == len(self.delta) == len(self.speed) == rows:
            return
        del self.dt[m:], self.delta[m:], self.speed[m:]
        if order > 1:
            kept, total = [], 0
            for block in self.slopes:
                if total >= m:
                    break
                kept.append(block[:m - total])
                total += len(kept[-1])
            self.slopes = kept
        self.observations = [o for o in self.observations if o[0] <= m]
        self.runs = [r for r in self.runs if r[0] < m]

    def inputs(self, delta, order: int):
        """The steps' inputs w (m, order) of the group: ``delta`` (m,) (w_0, shifted) and the derivatives."""
        if order == 1:
            return delta[:, None]
        w = np.empty((len(delta), order))
        w[:, 0] = delta
        w[:, 1:] = self.slopes[0] if len(self.slopes) == 1 else np.concatenate(self.slopes)
        return w


class EKFEstimator(OnlineEstimator):
    """Augmented-state EKF. See :class:`~online_id.filters.base.OnlineEstimator` for the API."""

    name = "ekf"

    def _init_filter(self, x0, P0):
        #: the length of each step's input w (model/intersample.py): the hold's δ alone, or a cubic's 4
        self._order = 1 if self.config.intersample == "hold" else ORDER
        compile_now(self.theta0, self.known, self._order)  # (a live run must not stall at its first sample)
        block_close.compile_now(len(x0))  # (nor at its first correction)
        if not self.augment:
            block_close.compile_close(len(self.theta0), len(x0), self._order)
        self._kf = _MeanAlreadyPropagatedEKF(dim_x=len(x0), dim_z=N_OUT)
        self._kf.x = x0.copy()
        self._kf.P = P0.copy()
        self._model = None  # LocalModel: the steps around a linearisation point
        self._outputs = None  # LinearOutputs at the current parameters
        self._parameters_moved = True
        self._delta_shift = 0.0  # g·e: the extra states' shift of the road-wheel angle [rad]
        self._pending = _Pending()
        self._F_x_identity = np.eye(N_STATES, len(x0))
        self._F_block = np.eye(len(x0))  # F of a block; the model states' rows are rewritten at each flush
        self._no_offset = np.zeros(N_OUT)
        self._staged = None  # a whole block taken at once by _stage_block, until _close_block works it
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

    def _estimate_arrays(self):
        # (x and P are replaced at every correction, reset and _set; a group's catch-up writes only x's model
        # states in place, and the health's divergence goes through _set)
        return self._kf.x, self._kf.P, self.diverged_at

    def _extra_mean(self):
        return self._kf.x[N_AUG:]

    def _sync(self):
        self._catch_up()

    def _set(self, x, P):
        self._pending.clear()
        self._staged = None
        self._kf.x = x
        self._kf.P = P
        self._parameters_moved = True
        self._start_block()

    def _start_block(self):
        # ∂(model states now)/∂(augmented state at block start): the identity, shared (F_x is replaced, never
        # written in place: a group's catch-up gives it a new array)
        self._F_x = self._F_x_identity
        self._elapsed = 0.0
        self._P_start = None  # P at the block start, once the block's covariance was propagated
        sums = getattr(self, "_sums", None)
        if sums is None or not sums.empty:  # (an empty block's: kept)
            self._sums = BlockSums(N_OUT, len(self._kf.x), N_STATES)
        self._gate_threshold = None
        self._block_samples = 0  # samples propagated in the block
        self._observed_at = []  # the number of samples propagated when each observation came
        self._gap_at = None  # observations before a long gap's state variance (sample_gaps.py) arrived
        self._gap_variance = 0.0
        self._since_gate = GATE_REFRESH  # observations since the gate's refresh: the block's first sample refreshes it
        self._refresh_gate = False  # the pending group starts with a gate refresh

    # -- predict ---------------------------------------------------------------------------------------
    def _propagate(self, dt, w, speed):
        model = self._model
        if self._parameters_moved or model is None:
            self._catch_up()  # the pending samples belong to the old parameters
            self._linearise(speed)
        elif abs(speed - model.speed) > self.config.speed_tolerance * model.speed:
            # a new point for the speed alone: the outputs do not depend on V (filters/local_model.py), so
            # they and the pending group stay; the group's next samples take the new point's steps
            self._cover(self._kf.x[PARAMS], speed)
        if self._since_gate >= GATE_REFRESH or len(self._pending) >= MAX_GROUP:
            self._catch_up()
            self._refresh_gate = True
            self._since_gate = 0
        pending = self._pending
        if not pending.runs or pending.runs[-1][1] is not self._model:
            pending.runs.append((len(pending), self._model))
        pending.dt.append(dt)
        pending.delta.append(float(w[0]) + self._delta_shift)  # the road-wheel angle the car sees
        if self._order > 1:
            pending.slopes.append(w[None, 1:self._order])
        pending.speed.append(speed)
        self._elapsed += dt
        self._block_samples += 1

    def _propagate_observe_many(self, dt, w, speed_held, values, mask, delta, speed, observe):
        """The array path's runs of samples (filters/feeding.py ``update_many``): what ``_propagate`` and
        ``_observe`` do sample by sample, with the samples between two events (a new linearisation point, a
        gate refresh, a group's end) appended to the pending group at once."""
        m = len(dt)
        w = np.asarray(w)
        delta_held = w[:, 0].tolist()  # (the input's value; its derivatives, if any, are appended as rows)
        order = self._order
        pending = self._pending
        tol = self.config.speed_tolerance
        k = 0
        while k < m:
            model = self._model
            if (self._parameters_moved or model is None or self._since_gate >= GATE_REFRESH
                    or len(pending.dt) >= MAX_GROUP or not _zero(self._gap_state_variance)
                    or abs(speed_held[k] - model.speed) > tol * model.speed):
                self._propagate(dt[k], w[k], speed_held[k])
                if observe[k]:
                    self._observe(values[k], mask, delta[k], speed[k])
                k += 1
                continue
            # samples k..j-1: nothing happens at any of them but their appends
            j, since, size = k, self._since_gate, len(pending.dt)
            model_speed, within = model.speed, tol * model.speed
            while j < m and since < GATE_REFRESH and size < MAX_GROUP and (
                    abs(speed_held[j] - model_speed) <= within):
                since += observe[j]  # (a sample propagated, not learned from, does not count towards the gate)
                j += 1
                size += 1
            if not pending.runs or pending.runs[-1][1] is not model:
                pending.runs.append((len(pending.dt), model))
            shift = self._delta_shift
            first = len(pending.dt)
            pending.dt.extend(dt[k:j])
            pending.delta.extend([d + shift for d in delta_held[k:j]])
            if order > 1:
                pending.slopes.append(w[k:j, 1:order])
            pending.speed.extend(speed_held[k:j])
            elapsed, samples = self._elapsed, self._block_samples
            observations, observed_at = pending.observations, self._observed_at
            for i in range(k, j):
                elapsed += dt[i]
                samples += 1
                if observe[i]:
                    observations.append((first + i - k + 1, values[i], mask, delta[i] + shift))
                    observed_at.append(samples)
            self._elapsed, self._block_samples, self._since_gate = elapsed, samples, since
            k = j

    def _stage_block(self, dt, w, speed_held, values, mask, delta, speed, observe):
        """A run of the array path that is a whole block, closed by the correction that follows (feeding.py
        ``_plain_run``), kept as it is for :meth:`_close_block`'s compiled call instead of appended to the
        pending group sample by sample: where that call takes the block (no extra states, every sample observed,
        one linearisation point, no gap, a group whose gate is refreshed at its first sample only). Elsewhere
        False, nothing done: the samples go to :meth:`_propagate_observe_many`. The same numbers either way."""
        m = len(dt)
        if (self.augment or self._block_samples or len(self._pending) or m > GATE_REFRESH
                or self._since_gate < GATE_REFRESH or not all(observe) or not _zero(self._gap_state_variance)
                or self._P_start is not None or not self._sums.empty or self._gap_at is not None
                or not one_period(dt)):
            return False
        first = speed_held[0]
        if self._parameters_moved or self._model is None:  # (what _propagate does at the first sample)
            self._linearise(first)
        elif abs(first - self._model.speed) > self.config.speed_tolerance * self._model.speed:
            self._cover(self._kf.x[PARAMS], first)
        model = self._model
        within = self.config.speed_tolerance * model.speed
        if type(model) is not LocalModel or any(abs(v - model.speed) > within for v in speed_held):
            self._unstage((dt, w, speed_held, values, mask, delta, speed, observe))
            return True  # (the samples are in the pending group now, as _propagate_observe_many puts them)
        self._staged = (dt, w, speed_held, values, mask, delta, speed, observe)
        return True

    def _unstage(self, staged=None):
        """The staged block's samples (or ``staged``'s) into the pending group, as _propagate_observe_many
        appends them."""
        if staged is None:
            staged, self._staged = self._staged, None
        self._propagate_observe_many(*staged)

    def _close_staged(self):
        """:meth:`_close_block` of a staged block: its compiled call on the run's own arrays; None (the samples
        then in the pending group, for the steps one by one) where that call does not take it."""
        dt, w, speed_held, values, mask, delta, speed, observe = self._staged
        m = len(dt)
        elapsed = 0.0
        for h in dt:  # (as _propagate adds them)
            elapsed += h
        closed = self._close_in_one_call(
            self._model, dt, elapsed, speed_held, np.ascontiguousarray(np.asarray(w, dtype=float)[:, :self._order]),
            np.ascontiguousarray(values, dtype=float), np.array(delta), mask, m * (m + 1) // 2 / m / m)
        if closed is None:
            self._unstage()
        else:
            self._staged = None
        return closed

    def _close_in_one_call(self, model, periods, elapsed, speeds, w, values, deltas, mask, share):
        """The compiled close (filters/block_close.py ``close_block``) of a block of m samples at ``model``'s point
        and one period (``periods`` (m,)), ``elapsed`` [s] long, its step speeds, inputs ``w`` (m, K), observed
        ``values`` (m, n_out) and road-wheel angles ``deltas`` (m,) under one ``mask``; ``share`` the observations'
        share of the process noise. Returns (channels, ν, diag S) with the correction applied, or None with
        nothing done (the random walk's tally put back)."""
        m = len(periods)
        Phi0, L, columns, inputs = model._tables(sum(periods) / m)
        G0, LG = inputs if inputs is not None else (_NO_INPUTS, np.empty((len(L), 0)))  # (the hold's: none)
        outputs = self._outputs
        walked = self._random_walk_variance
        q = self._process_noise(elapsed)
        x, P = self._kf.x, self._kf.P
        try:
            status, x_new, P_new, nu, S = block_close.close_block(
                Phi0, L, columns, G0, LG, x[PARAMS] - model.s, np.array(speeds) - model.speed, w, x, self._F_x,
                outputs.C, outputs.D, outputs.dC, outputs.dD, values, deltas, mask, self._R_now,
                self.config.gate_sigma ** 2, P, q, share)
        except np.linalg.LinAlgError:  # (a singular S: the steps one by one say so as they did)
            status = -1
        if status:
            self._random_walk_variance = walked  # (the steps one by one tally it)
            return None
        self._kf.x, self._kf.P = x_new, P_new
        self._elapsed = 0.0
        self._parameters_moved = True
        channels = self._mask_channels
        if channels[0] is not mask:  # (the masks are shared objects, one per pattern of channels)
            channels = self._mask_channels = (mask, np.flatnonzero(mask))
        return channels[1], nu, S.diagonal()

    _mask_channels = (None, None)  # (the last one-call close's mask, its channels)

    def _linearise(self, speed):
        """A new linearisation point where the current one no longer covers (s, V); outputs at s (and at
        the extra states e, constant until the next correction)."""
        s = self._kf.x[PARAMS]
        self._cover(s, speed)
        self._outputs = self._model.outputs(s)
        if self.augment:
            e = self._kf.x[N_AUG:]
            self._delta_shift = float(self.augment.steering_shift(e))
            rates = self._model.output_rates() if self.augment.has_lags else None
            self._outputs = self._outputs.with_extra_states(self.augment, e, rates)
        self._parameters_moved = False

    def _cover(self, s, speed):
        """Make the current linearisation point one that covers (s, speed): a new one where it does not."""
        if self._model is None or not self._model.covers(s, speed):
            cfg = self.config
            self._model = local_model(self.theta0, s, speed, self.known, cfg.relinearise_log_step,
                                      cfg.speed_tolerance, self._order)

    def _catch_up(self):
        """Predict the pending samples as one group: mean, chained Jacobians, then gate and sum the
        group's observations."""
        if self._staged is not None:  # (read before its correction: an interruption, say)
            self._unstage()
        pending = self._pending
        pending.mend(self._order)  # (after an interruption inside an append; nothing otherwise)
        m = len(pending)
        if not m:
            return
        speeds, periods = pending.speed, pending.dt
        one_speed = speeds.count(speeds[0]) == m  # (on the lists: the checks below cost more than the arithmetic)
        period = one_period(periods)
        dt, d, V = np.array(periods), np.array(pending.delta), np.array(speeds)
        w = pending.inputs(d, self._order)
        observations, runs = pending.observations, pending.runs
        pending.clear()
        s = self._kf.x[PARAMS]
        if len(runs) == 1 and period and one_speed and type(runs[0][1]) is LocalModel:
            steps = runs[0][1].step(s, sum(periods) / m, speeds[0])  # one step repeated (numpy's mean of a few)
            X, F = self._recursed([(0, m, steps)], w)
        elif period or any(type(model) is not LocalModel for _, model in runs):
            # one period (tables per point), or an exact fallback's steps: each run of samples (the speed may
            # cross linearisation points) takes its own point's steps
            parts = [(a, b, model.steps(s, dt[a:b], V[a:b])) for a, b, model in _spans(runs, m)]
            if all(type(steps) is _TableGroupSteps for _, _, steps in parts):
                X, F = self._recursed(parts, w)
            else:
                A, T = transition_table(_stacked([steps.Ad for _, _, steps in parts]))
                X, F = self._tabled(A, T, parts, w)
        else:  # a period that changes at every sample (a CAN log's jitter): sample by sample, compiled
            X, F = self._jittered(runs, s, dt, w, V)
        self._kf.x[:N_STATES] = X[m]
        self._F_x = F[m].copy()
        if self._refresh_gate:
            self._refresh_gate = False
            delta = observations[0][3] if observations and observations[0][0] == 1 else d[0]
            H = self._outputs.sensitivity(F[1], X[1], delta)
            self._gate_threshold = block_close.gate_threshold(H, self._kf.P, self._R_now, self.config.gate_sigma ** 2)
        if observations:
            self._absorb(observations, X, F)

    def _recursed(self, parts, w):
        """X and F of a group whose runs' steps come from one-period tables (filters/local_model.py), by the
        recursion in one compiled loop (filters/groups.py ``recurse_group``): the unrolled products of
        :meth:`_tabled` cost a dozen array operations a group. ``w`` (m, K): the steps' inputs."""
        m, K = w.shape
        Ad = np.empty((m, N_STATES, N_STATES))
        Gamma = np.empty((m, N_STATES, K))
        run_of = np.empty(m, dtype=np.int64)
        for r, (a, b, steps) in enumerate(parts):
            Ad[a:b], Gamma[a:b], run_of[a:b] = steps.Ad, steps.Gamma, r  # (one step repeated, or one per sample)
        columns = (parts[0][2].columns_table[None] if len(parts) == 1  # (one point: its table, without a copy)
                   else np.stack([steps.columns_table for _, _, steps in parts]))
        X = np.empty((m + 1, N_STATES))
        F = np.empty((m + 1,) + self._F_x.shape)
        X[0], F[0] = self._kf.x[:N_STATES], self._F_x
        steering = self.augment.steering if self.augment else _NO_STEERING
        recurse_group(Ad, Gamma, columns, run_of, np.ascontiguousarray(steering, dtype=float), w, X, F)
        return X, F

    def _tabled(self, A, T, parts, w):
        """X and F of a group from its transition table (filters/groups.py) and its runs' steps."""
        Gamma = _stacked([steps.Gamma for _, _, steps in parts])
        inputs = Gamma[:, :, 0] * w[:, :1] if w.shape[1] == 1 else np.einsum("mak,mk->ma", Gamma, w)
        X = propagate_mean(A, T, self._kf.x[:N_STATES], inputs)
        columns = _stacked([self._step_columns(steps, X[a:b], w[a:b]) for a, b, steps in parts])
        return X, chain_jacobians(A, T, self._F_x, columns)

    def _jittered(self, runs, s, dt, w, V):
        """X and F of a group whose sample period varies, run by run (filters/spectral_group.py)."""
        m = len(dt)
        X = np.empty((m + 1, N_STATES))
        F = np.empty((m + 1,) + self._F_x.shape)
        X[0], F[0] = self._kf.x[:N_STATES], self._F_x
        steering = self.augment.steering if self.augment else None
        for a, b, model in _spans(runs, m):
            propagate_group(model.form, dt[a:b], s - model.s, V[a:b] - model.speed, w[a:b], X[a:b + 1],
                            F[a:b + 1], steering)
        return X, F

    def _step_columns(self, steps, x_before, w):
        """Each step's sensitivity to the constant states (m, 6, P + n): the parameters', then the extra
        states' Bd_j gᵀ (e moves every sample's input value by g·e: a constant shift, w_0 only)."""
        columns = steps.parameter_columns(x_before, w)
        if not self.augment:
            return columns
        extra = np.broadcast_to(steps.Bd[:, :, None] * self.augment.steering, (len(w), N_STATES, self.augment.n))
        return np.concatenate([columns, extra], axis=2)

    def _flush(self):
        """Propagate the covariance over the block: P ← F P Fᵀ + Q with the chained F."""
        self._catch_up()
        if self._elapsed == 0.0:
            return
        F = self._F_block
        F[:N_STATES] = self._F_x
        self._gap_variance = self._gap_state_variance  # (the process noise below takes it in)
        self._q = self._process_noise(self._elapsed)
        self._P_start = self._kf.P
        # filterpy's predict (P ← F P Fᵀ + Q; its predict_x is a no-op here) in one compiled call
        self._kf.P = predict_covariance(F, self._P_start, self._q)
        self._elapsed = 0.0

    def _close_block(self):
        """An ordinary block's whole close in one compiled call (filters/block_close.py ``close_block``): the
        block's samples one pending group at one linearisation point and one period, every sample observed under
        one mask, no extra states, no gap. Returns (channels, ν, diag S) with the correction applied, or None
        (nothing done: the health's steps then take the block one by one, with the same arithmetic; also where
        a sample or a channel fails its gate, or the numbers break down)."""
        if self._staged is not None:
            return self._close_staged()
        pending = self._pending
        pending.mend(self._order)
        m = len(pending)
        if (not m or self.augment or m != self._block_samples
                or len(pending.observations) != m or len(pending.runs) != 1 or not self._refresh_gate
                or self._P_start is not None or not self._sums.empty or self._gap_at is not None
                or not _zero(self._gap_state_variance)):
            return None
        model = pending.runs[0][1]
        periods = pending.dt
        if type(model) is not LocalModel or model is not self._model or not one_period(periods):
            return None
        observations = pending.observations
        mask = observations[0][2]
        if not all(o[2] is mask for o in observations):
            return None
        closed = self._close_in_one_call(
            model, periods, self._elapsed, pending.speed, pending.inputs(np.array(pending.delta), self._order),
            np.array([o[1] for o in observations], dtype=float), np.array([o[3] for o in observations]), mask,
            sum(self._observed_at) / m / m)
        if closed is not None:
            pending.clear()
        return closed

    # -- update ----------------------------------------------------------------------------------------
    def _observe(self, values, mask, delta, speed):
        self._pending.observations.append((len(self._pending), values, mask, delta + self._delta_shift))
        if self._gap_at is None and not _zero(self._gap_state_variance):  # a long gap just before this sample
            self._gap_at = len(self._observed_at)
        self._observed_at.append(self._block_samples)
        self._since_gate += 1

    def _absorb(self, observations, X, F):
        """Gate the group's observations against the threshold and add them to the block sums."""
        mask = observations[0][2]
        values = np.array([o[1] for o in observations], dtype=float)
        deltas = np.array([o[3] for o in observations])
        if len(observations) == len(X) - 1:  # every sample of the group observed (the usual case)
            if all(o[2] is mask for o in observations):  # under one (shared, read-only) mask: one compiled call
                outputs = self._outputs
                offset = self._no_offset if outputs.offset is None else outputs.offset
                ok, sum_z, sum_F, sum_x, sum_delta = block_close.accept_group(
                    outputs.C, outputs.D, offset, X, F, values, deltas, self._gate_threshold, mask)
                if ok:  # every usable channel of every sample accepted: the cheap path
                    self._sums.add_accepted(mask, outputs, len(observations), sum_z, sum_F, sum_x, sum_delta)
                    return
            Xo, Fo = X[1:], F[1:]
            idx = range(1, len(X))
        else:
            idx = [o[0] for o in observations]
            Xo, Fo = X[idx], F[idx]
        Y = self._outputs.predict(Xo, deltas)
        r = values - Y
        shared = all(o[2] is mask for o in observations)  # one (shared, read-only) mask object: the usual case
        masks = mask if shared else np.array([o[2] for o in observations])
        ok = (r * r <= self._gate_threshold) | ~masks  # a channel without a value is never rejected
        if shared and ok.all():  # every usable channel accepted under one mask: the cheap path
            # (the values of unusable channels are summed too; channels without samples are not read)
            self._sums.add_accepted(mask, self._outputs, len(observations), values.sum(axis=0),
                                    Fo.sum(axis=0), Xo.sum(axis=0), deltas.sum())
            return
        for i, j in enumerate(idx):  # a rejection or a change of usable channels: sample by sample
            self._absorb_one(values[i], observations[i][2], deltas[i], X[j], F[j], Y[i], ok[i])

    def _absorb_one(self, values, mask, delta, x, F_x, y, ok):
        if ok.all():
            self._sums.add_accepted(mask, self._outputs, 1, np.where(mask, values, 0.0), F_x, x, delta)
            return
        accept = mask & ok
        rejected = mask & ~accept
        if rejected.any():
            self.health.count_outliers(rejected)
        if accept.any():
            self._sums.add_channels(accept, values, y, self._outputs.sensitivity(F_x, x, delta))

    def _block_innovation(self):
        means = self._sums.means()
        if means is None or self._P_start is None:
            return None
        channels, z, zp, Hbar = means  # H̄ refers to the block-start state (module docstring)
        q = observed_process_noise(self._q, self._gap_variance, self._gap_at, self._observed_at,
                                   self._block_samples)
        C, S = block_covariances(Hbar, self._outputs.C[channels], q, self._P_start, self._F_block,
                                 self._R_now[channels] / self._sums.n[channels])
        self._block = (z, zp, C, S)
        return channels, z, zp, S

    def _apply_correction(self, keep):
        self._kf.x, self._kf.P = joseph_update(self._kf.x, self._kf.P, self._block, keep)
        self._parameters_moved = True
