"""The online estimator: the model's 6 states plus 8 log-scale parameters, one sample at a time.

Augmented state (Macchi et al. eq 15)::

    z = [r, β, φ, p, α1, α2, s_Mzz, ..., s_b2],   θ_i = θ0_i · exp(s_i)

where θ0 is the prior (constructor values or a batch fit); the parameters
follow a random walk. Working in s keeps θ positive and the problem scaled.

:class:`OnlineEstimator` holds everything the EKF and UKF share: time
bookkeeping, the guards (low speed, gaps, invalid samples, outlier gating,
covariance health), and the reading of the estimate.

Block-averaged corrections. The filter predicts every sample but corrects
every k-th (Macchi's "every few integration steps"), and the correction uses
the block mean of each channel over the k samples, with noise variance R/n and
the exact sensitivity of that mean to the state: no measurement is thrown
away, so k = 10 costs almost no accuracy (measured: final σ within ~1.5× of the
every-sample filter). Each sample is gated against its own predicted spread
before it enters the mean, so a spike is rejected alone.

A variant implements the hooks: ``_init_filter``, ``_set``, ``_propagate``
(advance the mean one sample), ``_observe`` (a sample's measurements into the
block), ``_flush`` (bring the covariance up to date), ``_block_innovation`` and
``_apply_correction`` (the update with the block means), ``_start_block``.

Streaming API (river's shape)::

    est = EKFEstimator(vehicle)
    for sample in source:
        est.update(sample)
    est.parameters, est.parameter_std
"""

from __future__ import annotations

import math
import warnings
from collections import Counter

import numpy as np

from online_id.errors import DivergedWarning, SensorOffsetWarning
from online_id.filters.augment import Augmentation
from online_id.filters.config import (
    MAX_BLOCK_S,
    MAX_RETEMPERS,
    RESTART_PERIODS,
    RETEMPER_FACTOR,
    FilterConfig,
    tempering_at,
)
from online_id.filters.innovations import InnovationLog
from online_id.filters.kinematics import KinematicBalance
from online_id.filters.lagged import Retimer
from online_id.filters.prior import centre_with_fixed, fixed_mask, informed_flags, prior_spread
from online_id.model.intersample import LOOKAHEAD, InputStream, run_inputs, split_step
from online_id.model.lateral import N_PARAMS, N_STATES
from online_id.stream.gaps import GAP_FACTOR, SampleClock, bridge_inputs
from online_id.stream.samples import MEASURED_CHANNELS, Sample, SampleArrays
from online_id.vehicle.loader import Vehicle
from online_id.vehicle.parameters import PARAMETER_NAMES, Parameters

N_AUG = N_STATES + N_PARAMS
#: The log-scale parameters in the augmented state; extra states (offsets, effects) follow them.
PARAMS = slice(N_STATES, N_AUG)

#: A log-scale parameter beyond ±this has left e^±5 = 0.007x-150x of its prior: no car is that far
#: from its constructor's figures, so the filter has diverged and is reset.
MAX_LOG_SCALE = 5.0
#: The channels whose offsets a_y − V·r shows (filters/kinematics.py).
KINEMATIC_OFFSET_CHANNELS = ("lateral_acceleration", "yaw_rate")
#: Corrections between full positive-definiteness checks of P (a Cholesky): Joseph-form updates keep P
#: positive-definite, so a check every 50 catches round-off drift without paying one per correction.
FULL_CHECK_EVERY = 50
_YAW, _AY = MEASURED_CHANNELS.index("yaw_rate"), MEASURED_CHANNELS.index("lateral_acceleration")
#: The lateral velocity: worked per unit speed, as the sideslip angle v_y / V (model/lateral.py VY), its noise
#: variance R [(m/s)²] divided by V² (:attr:`OnlineEstimator._R_now`).
_VY = MEASURED_CHANNELS.index("lateral_velocity")


class OnlineEstimator:
    """Base class of the augmented-state filters. See the module docstring.

    Parameters
    ----------
    vehicle : the car (known constants, prior)
    prior : centre of the log-scale parameters (default: the vehicle's prior)
    prior_log_std : initial 1σ of each log-scale parameter, shape (8,) (default: the vehicle's
        relative standard errors widened to ``config.prior_log_std_floor``; what was widened is in
        :attr:`prior_spread`, see :mod:`online_id.filters.prior`)
    initial : parameter values the filter starts from (default: ``prior``)
    config : :class:`FilterConfig`
    fixed : {name: value [SI]} held fixed: zero variance, no random walk, never updated
    augment : extra states estimated with the 8 (:class:`~online_id.filters.augment.Augmentation`:
        sensor offsets, effect parameters), appended after the parameters; none by default
    """

    name = "base"
    #: The longest span of a correction's block [s] when FilterConfig.max_block_s is None.
    max_block_s = MAX_BLOCK_S
    #: The estimate read (:attr:`log_scale`, :attr:`log_scale_std`) moves only at a correction or a guard's
    #: action, never while samples are propagated and observed: the array path (:meth:`update_many`) then
    #: reads the trace's rows inside a run of samples before the run; a variant for which it does not hold
    #: sets this False.
    _reading_moves_at_corrections = True

    def __init__(self, vehicle: Vehicle, prior: Parameters | None = None, prior_log_std=None,
                 initial: Parameters | None = None, config: FilterConfig | None = None,
                 fixed: dict[str, float] | None = None, augment: Augmentation | None = None):
        self.vehicle = vehicle
        self.augment = augment or Augmentation()
        self.n_aug = N_AUG + self.augment.n  # length of the augmented state
        self.known = vehicle.known
        self.config = config or FilterConfig()
        self.prior = prior or vehicle.prior
        self.prior_spread = prior_spread(vehicle.prior_relative_std.to_vector(), prior_log_std,
                                         self.config.prior_log_std_floor, fixed)
        self.fixed = self.prior_spread.fixed
        self._fixed = fixed_mask(self.fixed)
        self._free_aug = np.concatenate([np.ones(N_STATES, bool), ~self._fixed,  # what has a variance
                                         np.ones(self.augment.n, bool)])
        self._walk = (~self._fixed).astype(float)  # which parameters follow the random walk
        self.theta0 = centre_with_fixed(self.prior.to_vector(), self.fixed)
        self.prior_log_std = self.prior_spread.log_std * math.sqrt(self.config.p0_scale)
        s_init = np.zeros(N_PARAMS) if initial is None else np.log(initial.to_vector() / self.theta0)
        s_init[self._fixed] = 0.0
        self._R_nominal = np.array([self.config.measurement_std.get(c, np.nan) ** 2 for c in MEASURED_CHANNELS])
        #: the likelihood tempering until converged (FilterConfig.converging_r_scale at TEMPER_REFERENCE_RATE_HZ,
        #: scaled to the log's rate once its period is known: _scale_to_period)
        self._temper = self.config.converging_r_scale
        self._R_diag = self._R_nominal * self._temper
        self._configured = np.isfinite(self._R_nominal)
        self._configured.flags.writeable = False  # shared by every complete sample
        self._any_configured = bool(self._configured.any())
        self._masks_absent: dict[tuple, np.ndarray] = {}
        self._nis_mean = np.ones(len(MEASURED_CHANNELS))
        # sums of squared block innovations and their counts per channel (innovation_rms)
        self._innovation_sq, self._innovation_n = np.zeros(len(MEASURED_CHANNELS)), np.zeros(len(MEASURED_CHANNELS))
        self._random_walk_variance = 0.0
        self._last_adapt_time: float | None = None
        self._q_state = np.asarray(self.config.state_process_std, dtype=float) ** 2
        self._events: Counter = Counter()
        #: samples with a measured |a_y| beyond this [m/s²] are propagated, not learned from, and counted
        #: under the event named: the linear tyres' range (a variant with another model moves both)
        self._ay_limit, self._ay_limit_event = self.config.linear_range_ay, "outside_linear_range"
        #: the block innovations, normalised, for the consistency verdict (online_id.trust.consistency)
        self.innovations = InnovationLog()
        self._gated: Counter = Counter()
        self.reset_reasons: Counter = Counter()
        self._last_time: float | None = None  # the last sample worked
        self._last_input: tuple[float, float] | None = None  # (δ road wheel [rad], V [m/s])
        #: the inputs between samples (model/intersample.py): each step's w from the samples around it; with
        #: the cubic a sample is worked when the next has come (``_waiting``)
        self._inputs = InputStream(self.config.intersample)
        self._waiting: Sample | None = None
        self._accepted_time: float | None = None  # the last valid sample, worked or waiting
        #: the last sample worked (its estimate is the current one; with the cubic input, the one before the last fed)
        self.last_worked: Sample | None = None
        self._clock = SampleClock()
        self._period: float | None = None  # the clock's period the thresholds below were scaled to
        self._max_gap = self.config.max_gap_s
        self._correct_every = self.config.correct_every
        self._initial_state_variance = np.asarray(self.config.initial_state_std, dtype=float) ** 2
        self._gap_state_variance = 0.0  # added to the states' process noise at the next flush (sample_gaps.py)
        self._since_correction = 0
        self._states_valid = False
        self._converged = False
        self._settle_start = None
        self.converged_at: float | None = None
        #: when the filter diverged (config.diverged_resets resets within diverged_window_s), else None
        self.diverged_at: float | None = None
        #: why the parameters were held at the prior from ``diverged_at`` when not a divergence (None: diverged)
        self.held_because: str | None = None
        self._reset_times: list[float] = []
        #: a_y against V·r over the run, a parameter-free check for sensor offsets (filters/kinematics.py)
        self.kinematics = KinematicBalance()
        #: said once: a_y − V·r shows an offset the filter does not estimate
        self._offset_told = any(st.group == "offsets" and st.key in KINEMATIC_OFFSET_CHANNELS
                                for st in self.augment.states)
        self._corrections_since_full_check = 0
        #: per measured channel, the time of the first of its blocks rejected in a row (NaN: its last was kept)
        self._rejecting_since = np.full(len(MEASURED_CHANNELS), np.nan)
        self._seen = np.zeros(len(MEASURED_CHANNELS), dtype=bool)  # channels with a sample in the open block
        #: a delay's lagged-output form (filters/lagged.py): the samples held until the lagged channels arrive
        self._retimer = Retimer(self.config.max_gap_s) if self.augment.has_lags else None
        self._lags_read: list | None = None  # the extra states the reading's lags were set from
        x0 = np.concatenate([np.zeros(N_STATES), s_init, self.augment.initial])
        P0 = np.diag(np.concatenate([np.asarray(self.config.initial_state_std) ** 2, self.prior_log_std ** 2,
                                     self.augment.prior_std ** 2]))
        self._start = (x0.copy(), P0.copy())  # where a retempered start begins again (_retemper)
        self._retempers = 0
        self._init_filter(x0, P0)
        self._good = (self.x.copy(), self.P.copy())

    # -- hooks a variant implements ---------------------------------------------------------------
    def _init_filter(self, x0: np.ndarray, P0: np.ndarray) -> None:
        raise NotImplementedError

    @property
    def x(self) -> np.ndarray:
        """Augmented mean, shape (n_aug,) = (14 + extra states,)."""
        raise NotImplementedError

    @property
    def P(self) -> np.ndarray:
        """Augmented covariance, shape (n_aug, n_aug)."""
        raise NotImplementedError

    def _set(self, x: np.ndarray, P: np.ndarray) -> None:
        """Replace mean and covariance; abandons the current block."""
        raise NotImplementedError

    def _extra_mean(self) -> np.ndarray:
        """The extra states of the mean, (n,), without bringing the model states up to date (they change
        only at corrections)."""
        return self.x[N_AUG:]

    def _parameter_mean(self) -> np.ndarray:
        """The log-scale parameters of the mean, (8,), without bringing the model states up to date
        (a variant that works samples in groups overrides this: parameters only move at corrections)."""
        return self.x[PARAMS]

    def _sync(self) -> None:
        """Work any samples a variant holds back, so that the mean and the counts are current."""

    @property
    def _R_now(self) -> np.ndarray:
        """The measurement noise variances (5,) in the units the filter works: R, the lateral velocity's divided by
        the speed squared (it is worked as the sideslip angle v_y / V), at the last sample's speed (a block's
        span, 50 ms at most, moves V by a few per cent at 1 g)."""
        if not self._configured[_VY] or self._last_input is None:
            return self._R_diag
        R = self._R_diag.copy()
        R[_VY] /= self._last_input[1] ** 2
        return R

    def _si_scale(self, channels: np.ndarray):
        """Per channel of ``channels``, what turns a squared innovation in the filter's units into SI: 1, V² for the
        lateral velocity (worked per unit speed)."""
        if self._last_input is None or not (channels == _VY).any():
            return 1.0
        return np.where(channels == _VY, self._last_input[1] ** 2, 1.0)

    @property
    def _r_temper(self) -> float:
        return 1.0 if self._converged else self._temper

    def _process_noise(self, elapsed: float) -> np.ndarray:
        """Diagonal of Q over ``elapsed`` seconds; also tallies the parameters' random-walk variance."""
        q = self._q_param * elapsed
        self._random_walk_variance += q
        q_state = self._q_state * elapsed + self._gap_state_variance
        self._gap_state_variance = 0.0
        return np.concatenate([q_state, q * self._walk, self.augment.random_walk_variance * elapsed])

    @property
    def _q_param(self) -> float:
        """Random-walk variance per second of each log-scale parameter, now."""
        rw = self.config.parameter_random_walk if self._converged else self.config.converging_random_walk
        return rw ** 2

    def _propagate(self, dt: float, w: np.ndarray, speed: float) -> None:
        """Advance the mean by one step of ``dt`` [s] with the input ``w`` (4,) between its samples (the
        road-wheel angle's value and derivatives in normalised time, :mod:`online_id.model.intersample`; the
        hold's w is [δ, 0, 0, 0]) at the step's ``speed`` [m/s]."""
        raise NotImplementedError

    def _observe(self, values: np.ndarray, mask: np.ndarray, delta: float, speed: float) -> None:
        """Gate this sample's measurements (``mask`` marks the usable ones) and add them to the block.

        Rejected channels are reported with :meth:`_count_outliers`.
        """
        raise NotImplementedError

    def _flush(self) -> None:
        """Bring the covariance up to date with the samples propagated since the block started."""
        raise NotImplementedError

    def _block_innovation(self):
        """After ``_flush``: (channels, block means z (m,), predicted means (m,), S (m, m)) or None."""
        raise NotImplementedError

    def _apply_correction(self, keep: np.ndarray) -> None:
        """Update with the block means of the channels from ``_block_innovation`` where ``keep``."""
        raise NotImplementedError

    def _start_block(self) -> None:
        """Forget the block's measurements; the next block starts at the current state."""
        raise NotImplementedError

    # -- streaming API ------------------------------------------------------------------------------
    def update(self, sample: Sample) -> None:
        """Feed one sample. Never raises on bad data: problems are counted in :attr:`events`.

        With a delay among the extra states the sample is held until its lagged channels have arrived
        (filters/lagged.py), and worked then; :meth:`finish` works those still held at the end of a stream."""
        retimer = self._retimer
        if retimer is None:
            self._update(sample)
            return
        t = sample.time
        last = retimer.last_time
        if not _finite(t) or (last is not None and t <= last):  # the reading needs increasing times
            self._events["samples"] += 1
            self._events["invalid_samples"] += 1
            return
        self._read_lags()
        for s in retimer.push(sample):
            self._update(s)

    def finish(self) -> None:
        """The stream has ended: work the samples still held for a delay's lagged reading (their readings
        beyond the end are absent), and the one a cubic input waits with for its successor (its end slope
        one-sided). Without a delay or that sample, nothing to do."""
        if self._retimer is not None:
            self._read_lags()
            for s in self._retimer.drain():
                self._update(s)
        for _, w, v in self._inputs.drain():
            sample, self._waiting = self._waiting, None
            self._work(sample, w, v)

    @property
    def lookahead(self) -> int:
        """Samples a streaming ``update`` waits for before it works a sample (1 with the cubic input: the
        estimate after ``update(sample)`` is that of the samples before it; :meth:`finish` works the last)."""
        return LOOKAHEAD[self.config.intersample]

    def _read_lags(self) -> None:
        """Give the reading the current lags (they move only at corrections)."""
        e = self._extra_mean().tolist()
        if e != self._lags_read:
            self._lags_read = e
            self._retimer.set_lags(*self.augment.channel_lags(np.array(e)))

    def _accept(self, sample: Sample) -> bool:
        """Count the sample; whether it can be worked (finite time and inputs, time after the last valid one)."""
        self._events["samples"] += 1
        t, dH, V = sample.time, sample.steering_wheel_angle, sample.speed
        if not (_finite(t) and _finite(dH) and _finite(V)):
            self._events["invalid_samples"] += 1
            return False
        if self._accepted_time is not None and t <= self._accepted_time:
            self._events["invalid_samples"] += 1
            return False
        self._accepted_time = t
        return True

    def _update(self, sample: Sample) -> None:
        if not self._accept(sample):
            return
        ready = self._inputs.push(sample.time, sample.steering_wheel_angle / self.known.steering_ratio, sample.speed)
        if not self.lookahead:
            for _, w, v in ready:
                self._work(sample, w, v)
            return
        previous, self._waiting = self._waiting, sample  # (the cubic: the sample before is ready now, if any)
        for _, w, v in ready:
            self._work(previous, w, v)

    def _work(self, sample: Sample, w, v_step) -> None:
        """One valid sample: the step into it (input ``w``, speed ``v_step``: None for the first), its guards,
        its measurements, the correction when it closes a block."""
        self.last_worked = sample
        t, dH, V = sample.time, sample.steering_wheel_angle, sample.speed
        delta = dH / self.known.steering_ratio
        moving = abs(V) >= self.config.min_speed_mps
        observed = False
        if self._last_time is not None:
            dt = t - self._last_time
            prev_delta, prev_V = self._last_input
            missing = self._clock.missing(dt)
            self._clock.observe(dt)
            if self._clock.rough_period != self._period:
                self._scale_to_period(self._clock.rough_period)
            if missing:
                self._events["missing_samples"] += missing
            if dt > self._max_gap and self._period is not None:  # no period yet (3 steps): no step is a gap
                self._events["gaps"] += 1
                self._restart_states()
            elif not moving or abs(prev_V) < self.config.min_speed_mps:
                self._events["frozen_low_speed"] += 1
                self._restart_states()
            elif self._states_valid:
                if missing:  # see online_id/stream/gaps.py: hold δ across a gap and the fit is biased
                    if self.config.intersample == "hold":
                        h, deltas = bridge_inputs(dt, missing, prev_delta, delta)
                        parts = [(d, 0.0, 0.0, 0.0) for d in deltas.tolist()]
                    else:  # the step's own curve, cut into sub-steps of the period (one table)
                        h, parts = dt / (missing + 1), split_step(w, missing + 1)
                    for part in parts:
                        self._propagate(h, np.asarray(part, dtype=float), v_step)
                    if missing > self.config.max_bridged_samples:
                        self._gap_state_variance = self._gap_state_variance + self._initial_state_variance * min(
                            1.0, dt / self._max_gap)
                else:
                    self._propagate(dt, w, v_step)
                self._since_correction += 1
                values, mask = self._measurement_vector(sample)
                if mask[_VY]:  # the lateral velocity per unit speed: the sideslip angle (model/lateral.py VY)
                    values = _per_unit_speed(values, V)
                ay = sample.lateral_acceleration
                if _finite(ay) and _finite(sample.yaw_rate):
                    self.kinematics.add(dt, V, sample.yaw_rate, ay)
                if ay is not None and abs(ay) > self._ay_limit:
                    self._events[self._ay_limit_event] += 1  # propagated, not learned from
                elif self._any_configured if mask is self._configured else mask.any():
                    self._seen |= mask
                    self._observe(values, mask, delta, V)
                observed = True
        elif not moving:
            self._events["frozen_low_speed"] += 1
        self._last_time, self._last_input = t, (delta, V)
        if moving and not self._states_valid:
            self._states_valid = True  # the states restart here; the next samples inform them
            return
        if observed and self._since_correction >= self._correct_every:
            self._correct()

    def _scale_to_period(self, period: float | None) -> None:
        """The thresholds in time that a slow log's period would defeat (FilterConfig.max_gap_s, max_block_s), and
        the tempering, scaled to the log's rate (:data:`~online_id.filters.config.TEMPER_REFERENCE_RATE_HZ`)."""
        self._period = period
        if period is None or not period > 0:
            return
        self._max_gap = max(self.config.max_gap_s, RESTART_PERIODS * period)
        # the 1e-6: a period of exactly max_block_s / k in floating point still gives k
        span = self.max_block_s if self.config.max_block_s is None else self.config.max_block_s
        self._correct_every = max(1, min(self.config.correct_every, int(span / period + 1e-6)))
        temper = tempering_at(self.config.converging_r_scale, period) * RETEMPER_FACTOR ** self._retempers
        if not self._converged and temper != self._temper:
            self._R_diag = self._R_diag * (temper / self._temper)
        self._temper = temper

    def update_many(self, samples, *, start: int = 0, stop: int | None = None, record=None,
                    on_record=None) -> None:
        """Feed several samples: a :class:`~online_id.stream.samples.SampleArrays` (the array path, below), or
        any iterable of :class:`Sample` (fed one by one to :meth:`update`).

        The array path gives the numbers :meth:`update` gives for the same samples one by one (the test
        ``tests/test_array_path.py``): runs of ordinary samples (valid, moving, no gap, the same channels,
        every value finite, the period not being refreshed) go to the variant's
        :meth:`_propagate_observe_many` up to the sample that closes a block, whose correction follows as it
        would; any other sample (the first, a gap, a stop, a NaN, a spike of a_y, ...) goes through
        :meth:`update`, with every guard and warning. With a delay's lagged reading every sample does.

        ``start``, ``stop``: the rows to feed. ``record`` (n,) bool and ``on_record(k)``: called after row k
        where ``record[k]`` (the trace of online_id.estimation.run_estimator)."""
        if not isinstance(samples, SampleArrays):
            for s in samples:
                self.update(s)
            self.finish()
            return
        arrays = samples
        n = len(arrays) if stop is None else stop
        self.array_position = start  # the next row to feed (what was fed, should the run be interrupted)
        inputs = None if self._retimer is not None else self._array_inputs(arrays)
        if inputs is None or n <= start:
            for k in range(start, n):
                self.update(arrays.sample(k))
                self.array_position = k + 1
                if record is not None and record[k]:
                    on_record(k)
            self.finish()
            return
        W, S, slopes = inputs
        t, V = arrays.time, arrays.speed
        delta = arrays.steering_wheel_angle / self.known.steering_ratio
        values, absent = arrays.values, arrays.absent
        min_speed = self.config.min_speed_mps
        with np.errstate(invalid="ignore"):
            # a sample the fast path may take, judged alone: finite inputs and values, moving
            alone = (np.isfinite(t) & np.isfinite(delta) & np.isfinite(V) & (np.abs(V) >= min_speed)
                     & (np.isfinite(values) | absent).all(axis=1))
            # and with the sample before it: times increasing, the one before also such a sample
            step = np.empty(len(t))
            step[0] = np.nan
            step[1:] = t[1:] - t[:-1]
            plain = alone & (step > 0)
            plain[1:] &= alone[:-1] & (absent[1:] == absent[:-1]).all(axis=1)  # (and the same channels)

        def one(k: int) -> None:
            """Sample k through the streaming path's checks and work (a guard, a gap, a change of channels: what
            update decides), with its step's input from the arrays."""
            sample = arrays.sample(k)
            if self._accept(sample):
                self._work(sample, None if np.isnan(W[k, 0]) else W[k], float(S[k]))
            self.array_position = k + 1
            if record is not None and record[k]:
                on_record(k)

        k = start
        while k < n:
            last = self._last_time
            if not (alone[k] and self._states_valid and last is not None and t[k] > last
                    and abs(self._last_input[1]) >= min_speed):
                one(k)
                k += 1
                continue
            # the longest run of plain samples from k that ends at the latest at the sample closing the block,
            # before a refresh that moves the period and at the first sample to record
            block_end = k + max(1, self._correct_every - self._since_correction)
            quiet = self._clock.quiet_steps()
            limit = min(n, block_end, k + quiet)
            if limit == k + quiet < min(n, block_end) and self._clock.period is not None:
                # the step that refreshes the period joins the run where it leaves the period as it is (a
                # steady clock: no threshold moves), as update would find
                r = k + quiet
                if self._clock.period_after(float(t[r] - (t[r - 1] if r > k else last))) == self._period:
                    limit = r + 1
            pattern = absent[k]
            h = self._clock.period
            # the longest step that is neither a gap (a restart) nor skips samples (bridged)
            longest = min(self._max_gap if self._period is not None else np.inf,
                          np.inf if h is None else GAP_FACTOR * h)
            first = t[k] - last  # (the sample before may have been left out: the step from the last one taken)
            j = k
            if limit > k and first <= longest:
                j = k + 1
                if j < limit:
                    ok = plain[j:limit] & (step[j:limit] <= longest)
                    if record is not None and not self._reading_moves_at_corrections:
                        ok &= ~record[j - 1:limit - 1]
                    j = limit if ok.all() else j + int(np.argmin(ok))
            if j == k:  # (a step that is a gap or skips samples, a change of channels, a period refresh)
                one(k)
                k += 1
                continue
            if record is not None and j - 1 > k:  # rows inside the run read the estimate as it is before it
                for i in np.flatnonzero(record[k:j - 1]).tolist():
                    on_record(k + i)
            self._plain_run(k, j, t, delta, V, values, pattern, first, step, W, S)
            self.array_position = j
            if record is not None and record[j - 1]:
                on_record(j - 1)
            k = j
        worked = np.flatnonzero(self._valid_of[:n]) if self._last_time is not None else ()
        if len(worked):  # a stream that goes on after these rows starts from the last
            r = int(worked[-1])
            r2 = int(worked[-2]) if len(worked) > 1 else None
            self._inputs.seed((float(t[r]), float(delta[r]), float(V[r])), float(slopes[r]),
                              None if r2 is None else (float(t[r2]), float(delta[r2]), float(V[r2])))

    def takes_arrays(self, arrays: SampleArrays) -> bool:
        """Whether :meth:`update_many` takes ``arrays`` on the array path (else it streams them row by row: a
        delay's lagged reading, or an estimator fed before)."""
        return self._retimer is None and self._array_inputs(arrays) is not None

    def valid_rows(self, arrays: SampleArrays, after: float | None = None) -> np.ndarray:
        """Which rows of ``arrays`` this estimator works (n,) bool: finite time, steering and speed, and a time
        after every earlier such row's (and after ``after``): what :meth:`_accept` decides row by row."""
        t = arrays.time
        with np.errstate(invalid="ignore"):
            finite = np.isfinite(t) & np.isfinite(arrays.steering_wheel_angle) & np.isfinite(arrays.speed)
        latest = np.maximum.accumulate(np.where(finite, t, -np.inf))
        before = np.empty(len(t))
        if len(t):
            before[0] = -np.inf if after is None else after
            before[1:] = np.maximum(latest[:-1], before[0])
        return finite & (t > before)

    def _array_inputs(self, arrays: SampleArrays):
        """The step inputs of every row of ``arrays`` (model/intersample.py ``run_inputs``: W (n, 4), step speeds
        (n,), slopes (n,)), for an estimator that has not been fed before (else None: the rows are streamed);
        kept for further calls with the same arrays (``start``/``stop``)."""
        cached = getattr(self, "_inputs_of", None)
        if cached is not None and cached[0] is arrays:
            return cached[1]
        if self._accepted_time is not None or self._waiting is not None:
            return None
        valid = self.valid_rows(arrays)
        self._valid_of = valid
        delta = arrays.steering_wheel_angle / self.known.steering_ratio
        inputs = run_inputs(self.config.intersample, arrays.time, delta, arrays.speed, valid, slopes=True)
        self._inputs_of = (arrays, inputs)
        return inputs

    def _plain_run(self, a, b, t, delta, V, values, pattern, first, step, W, S) -> None:
        """Samples a..b-1 of the array path (:meth:`update_many`), each what :meth:`_update` would do with it
        (the same branches: moving, no gap, every value finite, one set of channels); ``first``: the step
        from the last sample taken to sample a; ``W``, ``S`` every row's step input and speed."""
        count = b - a
        self._events["samples"] += count
        self._accepted_time = float(t[b - 1])
        dts = [float(first)] + step[a + 1:b].tolist()
        self._clock.observe_many(dts)
        mask = self._configured if not pattern.any() else self._absent_mask(tuple(pattern.tolist()))
        vals = values[a:b]
        if not pattern[_VY]:  # the lateral velocity per unit speed: the sideslip angle (model/lateral.py VY)
            vals = vals.copy()
            vals[:, _VY] /= V[a:b]
        speeds = V[a:b].tolist()
        if not pattern[_AY] and not pattern[_YAW]:
            self.kinematics.add_many(dts, V[a:b], vals[:, _YAW], vals[:, _AY])
        usable = self._any_configured if mask is self._configured else bool(mask.any())
        if not pattern[_AY]:
            over = np.abs(vals[:, _AY]) > self._ay_limit
            n_over = int(np.count_nonzero(over))
            if n_over:
                self._events[self._ay_limit_event] += n_over
            observe = (~over).tolist() if usable else [False] * count
        else:
            observe = [usable] * count
        if usable and any(observe):
            self._seen |= mask
        self._propagate_observe_many(dts, W[a:b], S[a:b].tolist(), vals, mask, delta[a:b].tolist(), speeds, observe)
        self._since_correction += count
        self._last_time, self._last_input = float(t[b - 1]), (float(delta[b - 1]), speeds[-1])
        if self._since_correction >= self._correct_every:
            self.array_position = b - 1  # (the last sample counts as worked once its correction is done)
            self._correct()
        self.array_position = b

    def _propagate_observe_many(self, dt, w, speed_step, values, mask, delta, speed, observe) -> None:
        """``_propagate`` then, where ``observe``, ``_observe`` for each of several samples (lists; ``w`` (m, 4)
        the steps' inputs, ``values`` (m, 4)); a variant may do them at once, with the same numbers."""
        for k in range(len(dt)):
            self._propagate(dt[k], w[k], speed_step[k])
            if observe[k]:
                self._observe(values[k], mask, delta[k], speed[k])

    def _absent_mask(self, absent: tuple) -> np.ndarray:
        """The shared read-only mask of the configured channels less those ``absent`` (one per pattern)."""
        mask = self._masks_absent.get(absent)
        if mask is None:
            mask = self._masks_absent[absent] = self._configured & ~np.array(absent)
            mask.flags.writeable = False
        return mask

    def _measurement_vector(self, sample: Sample) -> tuple:
        """Measured values (4,) with 0.0 where unusable, and the mask of usable channels.

        The common case, every channel present and finite, returns the values as they came (a
        tuple) and the shared mask of configured channels, which must not be modified; likewise
        when some channels are absent (None) and the rest finite, with one shared mask per pattern.
        """
        m = sample.measurements()
        if None not in m and _all_finite(m):
            return m, self._configured
        if _all_finite([v for v in m if v is not None]):  # some channels absent (a log without roll)
            # one shared read-only mask per pattern, as for complete samples
            mask = self._absent_mask(tuple(v is None for v in m))
            return tuple(0.0 if v is None else v for v in m), mask
        present = self._configured & np.array([v is not None for v in m])
        values = np.array([np.nan if v is None else v for v in m], dtype=float)
        mask = present & np.isfinite(values)
        missing = int(np.count_nonzero(present & ~mask))
        if missing:
            self._events["missing_values"] += missing
        return np.where(mask, values, 0.0), mask

    def _count_outliers(self, rejected: np.ndarray) -> None:
        for i in np.flatnonzero(rejected):
            self._gated[MEASURED_CHANNELS[i]] += 1
            self._events["outliers_rejected"] += 1

    def _count_outlier_totals(self, rejected: np.ndarray) -> None:
        """As :meth:`_count_outliers` for several samples at once: ``rejected`` (4,) the count per channel."""
        for i in np.flatnonzero(rejected):
            self._gated[MEASURED_CHANNELS[i]] += int(rejected[i])
            self._events["outliers_rejected"] += int(rejected[i])

    # -- correction with gating and guards ----------------------------------------------------------
    def _correct(self) -> None:
        self._since_correction = 0
        try:
            self._flush()
            block = self._block_innovation()
            if block is None:
                # nothing usable in this block: still check the filter (a broken covariance
                # makes every sample fail its gate, and must not go unnoticed)
                self._start_block()
                if not self._listening(np.zeros(0, dtype=int)):
                    self._reopen()
                self._check_health()
                return
            channels, z, zp, S = block
            nis = (z - zp) ** 2 / np.diag(S)
            self._innovation_sq[channels] += (z - zp) ** 2 * self._si_scale(channels)
            self._innovation_n[channels] += 1
            keep = nis <= self.config.gate_sigma ** 2
            # signed innovation in σ of S, and S's R against the nominal R (the adapted R hides misfit)
            self.innovations.record(self._last_time, channels, (z - zp) / np.sqrt(np.diag(S)),
                                    self._R_diag[channels] / self._R_nominal[channels], self._converged)
            self._adapt_r(channels, nis)
            if not keep.all():
                self._events["blocks_rejected"] += int(np.count_nonzero(~keep))
            if keep.any():
                self._apply_correction(keep)
                self._events["corrections"] += 1
            self._start_block()
            if not self._listening(channels[keep]):
                self._reopen()
            if not self._offset_told:
                self._tell_offset()
        except (np.linalg.LinAlgError, FloatingPointError, ValueError) as exc:
            self._reset(f"{type(exc).__name__}: {exc}")
            return
        self._check_health()

    def _tell_offset(self) -> None:
        """Warn once, as soon as a_y − V·r shows an offset the filter does not estimate (the default run):
        the filter cannot learn what the model cannot produce, and may break down trying."""
        excess = self.kinematics.offset()
        if excess is None:
            return
        self._offset_told = True
        k = self.kinematics
        hold = self.diverged_at is None and not any(st.group == "offsets" for st in self.augment.states)
        warnings.warn(f"{self.name}: a_y − V·r averages {excess:+.3g} m/s² over the first {k.duration:.1f} s, beyond"
                      f" the ±{max(k.bound, 0):.2g} m/s² any car's sideslip allows: a sensor offset on"
                      f" lateral_acceleration ({excess:+.3g} m/s²) or yaw_rate ({-excess / k.mean_speed:+.3g} rad/s);"
                      + (" the parameters are no longer learned (held at the prior: what they learned from biased"
                         " data is not the car);" if hold else "")
                      + " --offsets estimates both", SensorOffsetWarning, stacklevel=4)
        if hold:  # (with the cubic between samples the biased run no longer broke the filter: it ran to Mzz 51x,
            # "informed"; issue 36)
            self._events["held_for_offset"] = 1
            self.held_because = (f"a_y − V·r showed a sensor offset the filter does not estimate at t ="
                                 f" {self._last_time:.1f} s")
            self._hold_at_prior()

    def kinematic_offset(self) -> float | None:
        """The mean of a_y − V·r over the run less what the estimated offsets explain, when beyond what the
        dynamics allow (filters/kinematics.py), else None [m/s²]."""
        expected = 0.0
        if self.augment:
            x = self.x
            for i, st in enumerate(self.augment.states):
                if st.group == "offsets" and st.key == "lateral_acceleration":
                    expected += float(x[N_AUG + i])
                elif st.group == "offsets" and st.key == "yaw_rate":
                    expected -= float(x[N_AUG + i]) * self.kinematics.mean_speed
        return self.kinematics.offset(expected)

    def _adapt_r(self, channels: np.ndarray, nis: np.ndarray) -> None:
        """Covariance matching: R_i = R_nominal_i · max(1, running mean of channel i's NIS).

        The NIS of a sample is clipped at the gate so that a rejected spike moves the mean
        by at most one gate's worth.
        """
        tau = self.config.adaptive_r_window_s
        t = self._last_time
        dt = 0.0 if self._last_adapt_time is None else t - self._last_adapt_time
        self._last_adapt_time = t
        if tau <= 0:
            return
        w = min(1.0, dt / tau)
        clipped = np.minimum(nis * self._R_diag[channels] / self._R_nominal[channels] / self._r_temper,
                             self.config.gate_sigma ** 2)
        self._nis_mean[channels] += w * (clipped - self._nis_mean[channels])
        self._R_diag[channels] = self._R_nominal[channels] * np.maximum(1.0, self._nis_mean[channels]) * (
            1.0 if self._converged else self._temper)

    def _check_health(self) -> None:
        x, P = self.x, self.P
        diag = P.diagonal()
        bad = None
        if not np.isfinite(x.sum() + P.sum()):
            bad = "NaN or inf in the filter state"
        elif diag[self._free_aug].min() <= 0:  # a fixed parameter's variance is 0 by design
            bad = "non-positive variance"
        elif diag[PARAMS].max() > self.config.max_parameter_std ** 2:
            bad = "parameter covariance exploded"
        elif np.abs(x[PARAMS]).max() > MAX_LOG_SCALE:
            bad = "a parameter left the range 0.007x-150x of its prior"
        else:
            self._corrections_since_full_check += 1
            if self._corrections_since_full_check >= FULL_CHECK_EVERY:
                self._corrections_since_full_check = 0
                try:
                    np.linalg.cholesky(P[np.ix_(self._free_aug, self._free_aug)])
                except np.linalg.LinAlgError:
                    bad = "covariance not positive-definite"
        if bad:
            self._reset(bad)
            return
        self._good = (x.copy(), P.copy())
        self._update_convergence(x[PARAMS], np.sqrt(diag[PARAMS]))

    def _update_convergence(self, s: np.ndarray, sd: np.ndarray) -> None:
        """Converged: every σ below ``converged_log_std`` and no parameter moved more than its σ
        since the start of the current ``settle_window_s`` window. Once converged, stays so."""
        if self._converged:
            return
        t = self._last_time
        if sd.max() >= self.config.converged_log_std:
            self._settle_start = None
            return
        if self._settle_start is None:
            self._settle_start = (t, s.copy())
            return
        t0, s0 = self._settle_start
        if np.any(np.abs(s - s0) > sd):
            self._settle_start = (t, s.copy())
        elif t - t0 >= self.config.settle_window_s:
            self._converged = True
            self.converged_at = t
            self._R_diag = self._R_diag / self._temper

    def _reset(self, why: str) -> None:
        self._events["resets"] += 1
        self.reset_reasons[why] += 1
        if self.reset_reasons[why] == 1:  # warn once per cause; the rest are counted
            warnings.warn(f"{self.name}: {why} at t = {self._last_time:.3f} s; reset to the last good state"
                          " (further resets for this cause are counted, not shown)", RuntimeWarning, stacklevel=3)
        x, P = self._good
        self._set(x.copy(), P.copy())
        self._corrections_since_full_check = 0
        self._restart_states()
        window = self.config.diverged_window_s
        self._reset_times = [t for t in self._reset_times if self._last_time - t < window] + [self._last_time]
        if self.diverged_at is None and len(self._reset_times) >= self.config.diverged_resets:
            # (a sensor offset that a_y − V·r shows is not cured by starting again: --offsets is; it diverges)
            if not self._converged and self._retempers < MAX_RETEMPERS and self.kinematic_offset() is None:
                self._retemper()
            else:
                self._diverge()

    def _retemper(self) -> None:
        """Resets in a burst before the filter converged: it learned faster than this log's fit to the model
        allows (the tempering is scaled to the rate for a log the model fits; the race car's, biased and past
        the model, ran its b1 to 1 % of the prior in 3 s at 100 Hz). Start the 8 parameters again from the prior
        (the extra states keep their values, with their prior variances back) with the tempering
        ×:data:`RETEMPER_FACTOR` (at most :data:`MAX_RETEMPERS` times; then the filter has diverged). Not when
        a_y − V·r shows a sensor offset the filter does not estimate (the filter then holds its parameters at the
        prior when it sees it, and the verdict points to --offsets). Counted as ``retempered``, said once."""
        self._retempers += 1
        self._events["retempered"] += 1
        old = self._temper
        self._temper = old * RETEMPER_FACTOR
        self._R_diag = self._R_diag * RETEMPER_FACTOR
        warnings.warn(f"{self.name}: {len(self._reset_times)} resets within {self.config.diverged_window_s:g} s up to"
                      f" t = {self._last_time:.3f} s before converging: the parameters start again from the prior,"
                      f" tempered {self._temper:g}x (was {old:g}x); this log fits the model less well than a clean"
                      " run", RuntimeWarning, stacklevel=4)
        self._reset_times = []
        self._flush_quiet()
        x0, P0 = self._start
        x, P = self.x.copy(), self.P.copy()
        x[PARAMS] = x0[PARAMS]  # (the extra states keep their values, with their prior variance back: a μ or an
        # offset learned is kept; the 8 are what ran away)
        P[N_STATES:, :] = 0.0
        P[:, N_STATES:] = 0.0
        P[N_STATES:, N_STATES:] = P0[N_STATES:, N_STATES:]
        self._set(x, P)
        self._good = (x.copy(), P.copy())
        self._settle_start = None
        self._restart_states()

    def _diverge(self) -> None:
        """Resets in a burst: the filter has diverged. Stop learning the parameters (they go back to the
        prior, with no variance inside the filter so that they stay there), keep filtering the model states
        and the extra states; the estimate reads as the prior with the prior's σ, not informed."""
        self._events["diverged"] = 1
        warnings.warn(f"{self.name}: {len(self._reset_times)} resets within {self.config.diverged_window_s:g} s up to"
                      f" t = {self._last_time:.3f} s: the filter diverged; its parameters are no longer learned"
                      " (held at the prior, reported with the prior's σ, not informed)", DivergedWarning, stacklevel=4)
        self._hold_at_prior()

    def _hold_at_prior(self) -> None:
        """Stop learning the parameters: back to the prior, no variance inside the filter (they stay there),
        reported at the prior with the prior's σ, not informed (``diverged_at``, :attr:`held_because`)."""
        self.diverged_at = self._last_time
        self._fixed = np.ones(N_PARAMS, dtype=bool)
        self._walk = np.zeros(N_PARAMS)
        self._free_aug = self._free_aug.copy()
        self._free_aug[PARAMS] = False
        self._flush_quiet()
        x, P = self.x.copy(), self.P.copy()
        x[PARAMS] = 0.0
        P[PARAMS, :] = 0.0
        P[:, PARAMS] = 0.0
        self._set(x, P)
        self._good = (x.copy(), P.copy())
        self._restart_states()

    def _listening(self, kept: np.ndarray) -> bool:
        """Track, per channel measured in the block just closed, whether the correction used it (``kept``: its
        index; a channel whose samples all failed the outlier gate, or whose block failed the block gate, was
        not). False when some channel has not been used for ``config.reopen_after_s``: the filter is lost."""
        since = self._rejecting_since
        ignored = self._seen.copy()
        ignored[kept] = False
        since[~ignored] = np.nan  # used, or not measured: no streak
        since[ignored & np.isnan(since)] = self._last_time
        self._seen[:] = False
        return not np.nanmax(self._last_time - since, initial=0.0) >= self.config.reopen_after_s

    def _reopen(self) -> None:
        """The gate has rejected a channel's every block for ``config.reopen_after_s``: the filter is lost.
        Raise the parameters' and extra states' variances back to a fraction of their prior's, forget their
        correlations, restart the model states."""
        self._events["reopened"] += 1
        if self._events["reopened"] == 1:
            lost = [c for c, t in zip(MEASURED_CHANNELS, self._rejecting_since)
                    if self._last_time - t >= self.config.reopen_after_s]
            warnings.warn(f"{self.name}: every correction from {', '.join(lost)} rejected for"
                          f" {self.config.reopen_after_s:g} s up to t = {self._last_time:.3f} s: the estimate is lost;"
                          " its covariance is reopened (further reopenings are counted, not shown)",
                          RuntimeWarning, stacklevel=3)
        self._rejecting_since[:] = np.nan
        self._flush_quiet()
        x, P = self.x.copy(), self.P.copy()
        prior = np.concatenate([self.prior_log_std ** 2, self.augment.prior_std ** 2]) * self.config.reopen_fraction
        var = np.maximum(np.diag(P)[N_STATES:], prior)
        var[:N_AUG - N_STATES][self._fixed] = 0.0
        P[N_STATES:, :] = 0.0
        P[:, N_STATES:] = 0.0
        P[N_STATES:, N_STATES:] = np.diag(var)
        self._set(x, P)
        self._restart_states()

    def _restart_states(self) -> None:
        """Forget the model states (after a dropout or a stop); keep the parameters and their covariance."""
        self._flush_quiet()
        x, P = self.x.copy(), self.P.copy()
        x[:N_STATES] = 0.0
        P[:N_STATES, :] = 0.0
        P[:, :N_STATES] = 0.0
        P[:N_STATES, :N_STATES] = np.diag(np.asarray(self.config.initial_state_std) ** 2)
        self._set(x, P)
        self._start_block()
        self._states_valid = False
        self._since_correction = 0

    def _flush_quiet(self) -> None:
        try:
            self._flush()
        except (np.linalg.LinAlgError, FloatingPointError, ValueError):
            x, P = self._good
            self._set(x.copy(), P.copy())

    # -- reading the estimate ----------------------------------------------------------------------
    @property
    def events(self) -> Counter:
        """Counts of what happened: samples, corrections, gaps, outliers_rejected, resets, ..."""
        self._sync()
        return self._events

    @property
    def gated(self) -> Counter:
        """Rejected outliers per measured channel."""
        self._sync()
        return self._gated

    @property
    def log_scale(self) -> np.ndarray:
        """Current log-scale parameters s, shape (8,)."""
        return self._parameter_mean().copy()

    @property
    def log_scale_std(self) -> np.ndarray:
        """1σ of s, shape (8,): close to the relative standard deviation of θ (the prior's once the filter
        diverged: it no longer learns them)."""
        if self.diverged_at is not None:
            return self.prior_log_std.copy()
        return np.sqrt(self.P.diagonal()[PARAMS])  # (read at every trace row: no np.diag copy)

    @property
    def parameters(self) -> Parameters:
        """Current estimate θ = θ0 · exp(s)."""
        return Parameters.from_vector(self.theta0 * np.exp(self.log_scale))

    @property
    def parameter_std(self) -> np.ndarray:
        """1σ of θ in SI units, shape (8,) (first-order: θ · σ_s)."""
        return self.theta0 * np.exp(self.log_scale) * self.log_scale_std

    @property
    def parameter_covariance(self) -> np.ndarray:
        """Covariance of θ (8, 8), first-order from the covariance of s."""
        theta = self.theta0 * np.exp(self._parameter_mean())
        if self.diverged_at is not None:
            return np.diag(self.prior_log_std ** 2) * np.outer(theta, theta)
        return self.P[PARAMS, PARAMS] * np.outer(theta, theta)

    @property
    def innovation_rms(self) -> dict[str, float]:
        """RMS of the block innovations (block mean measured − predicted) per channel [SI], over the
        run: what the model with its current states and parameters still misses."""
        self._sync()
        return {c: float(np.sqrt(sq / n)) for c, sq, n in zip(MEASURED_CHANNELS, self._innovation_sq,
                                                               self._innovation_n) if n}

    @property
    def extra_states(self) -> dict:
        """The extra states' values and 1σ, ``{"offsets": {channel: {value, std, unit}}, "effects": {...}}``
        (empty without extra states)."""
        if not self.augment:
            return {}
        x, P = self.x, self.P
        return self.augment.report(x[N_AUG:], np.sqrt(np.diag(P)[N_AUG:]))

    @property
    def informed(self) -> dict[str, bool]:
        """Per parameter: is the filter's own σ below ``uninformed_ratio`` of its prior σ
        (:func:`online_id.filters.prior.informed_flags`; a fixed parameter never is)? None of them once the filter
        diverged. The result of a run judges its σ after the run's widening (``EstimationResult.informed``)."""
        if self.diverged_at is not None:
            return {n: False for n in PARAMETER_NAMES}
        return informed_flags(self.log_scale_std, self.prior_log_std, self.fixed, self.config.uninformed_ratio)

    def _covariance_sqrt(self, M: np.ndarray) -> np.ndarray:
        """Upper Cholesky factor U (Uᵀ U = M) of an augmented covariance whose fixed parameters have no
        variance: factored on the rest, zero rows and columns for them (for sigma points)."""
        free = self._free_aug
        if free.all():  # nothing fixed (the usual case): the same factor without the index arrays
            return np.linalg.cholesky(M).T
        U = np.zeros_like(M)
        U[np.ix_(free, free)] = np.linalg.cholesky(M[np.ix_(free, free)]).T
        return U


def _per_unit_speed(values, speed: float):
    """``values`` (a tuple or an array of the measured channels) with the lateral velocity divided by ``speed``."""
    values = list(values) if isinstance(values, tuple) else values.copy()
    values[_VY] = values[_VY] / speed
    return values if not isinstance(values, list) else tuple(values)


def _finite(v) -> bool:
    return v is not None and math.isfinite(v)


def _all_finite(values) -> bool:
    isfinite = math.isfinite
    for v in values:
        if not isfinite(v):
            return False
    return True
