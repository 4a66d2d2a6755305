"""The online estimator: the model's 6 states plus 8 log-scale parameters, one sample at a time.

Augmented state (Macchi et al. eq 15)::

    z = [r, β, φ, p, α1, α2, s_Mzz, ..., s_b2],   θ_i = θ0_i · exp(s_i)

where θ0 is the prior (constructor values or a batch fit); the parameters
follow a random walk. Working in s keeps θ positive and the problem scaled.

:class:`OnlineEstimator` is what the EKF and UKF share, in three parts: this module (the augmented state, its
prior and noise, the reading of the estimate, the hooks a variant implements), the feeding of samples
(:mod:`online_id.filters.feeding`: time bookkeeping, the guards on a sample: low speed, gaps, invalid samples)
and the health it owns (:mod:`online_id.filters.health`: outlier gating, R adaptation, covariance health,
resets, convergence).

Block-averaged corrections. The filter predicts every sample but corrects
every k-th (Macchi's "every few integration steps"), and the correction uses
the block mean of each channel over the k samples, with noise variance R/n and
the exact sensitivity of that mean to the state: no measurement is thrown
away, so k = 10 costs almost no accuracy (measured: final σ within ~1.5× of the
every-sample filter). Each sample is gated against its own predicted spread
before it enters the mean, so a spike is rejected alone.

A variant implements the abstract hooks: ``_init_filter``, ``x``, ``P``, ``_set``, ``_propagate`` (advance the
mean one sample), ``_observe`` (a sample's measurements into the block), ``_flush`` (bring the covariance up to
date), ``_block_innovation`` and ``_apply_correction`` (the update with the block means), ``_start_block``; and
registers its name in :data:`online_id.filters.FILTERS`.

Streaming API (river's shape)::

    est = EKFEstimator(vehicle)
    for sample in source:
        est.update(sample)
    est.parameters, est.parameter_std
"""

from __future__ import annotations

import abc
import math
from collections import Counter

import numpy as np

from online_id.filters.augment import N_AUG, PARAMS, Augmentation
from online_id.filters.config import MAX_BLOCK_S, FilterConfig
from online_id.filters.feeding import _VY, SampleFeeding
from online_id.filters.health import NUMERICAL_ERRORS, FilterHealth, HealthReadings
from online_id.filters.kinematics import KinematicBalance
from online_id.filters.lagged import Retimer
from online_id.filters.prior import centre_with_fixed, fixed_mask, informed_flags, prior_spread
from online_id.model.intersample import InputStream
from online_id.model.lateral import N_PARAMS, N_STATES
from online_id.stream.gaps import SampleClock
from online_id.stream.samples import MEASURED_CHANNELS, Sample
from online_id.vehicle.loader import Vehicle
from online_id.vehicle.parameters import PARAMETER_NAMES, Parameters

__all__ = ["N_AUG", "PARAMS", "OnlineEstimator"]


class OnlineEstimator(SampleFeeding, HealthReadings, abc.ABC):
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
        #: gating, R adaptation, resets, convergence (filters/health.py)
        self.health = FilterHealth(self, self._R_nominal)
        self._configured = np.isfinite(self._R_nominal)
        self._configured.flags.writeable = False  # shared by every complete sample
        self._any_configured = bool(self._configured.any())
        self._masks_absent: dict[tuple, np.ndarray] = {}
        self._random_walk_variance = 0.0
        self._q_state = np.asarray(self.config.state_process_std, dtype=float) ** 2
        self._events: Counter = Counter()
        #: samples with a measured |a_y| beyond this [m/s²] are propagated, not learned from, and counted
        #: under the event named: the linear tyres' range (a variant with another model moves both)
        self._ay_limit, self._ay_limit_event = self.config.linear_range_ay, "outside_linear_range"
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
        #: a_y against V·r over the run, a parameter-free check for sensor offsets (filters/kinematics.py)
        self.kinematics = KinematicBalance()
        #: a delay's lagged-output form (filters/lagged.py): the samples held until the lagged channels arrive
        self._retimer = Retimer(self.config.max_gap_s) if self.augment.has_lags else None
        self._lags_read: list | None = None  # the extra states the reading's lags were set from
        x0 = np.concatenate([np.zeros(N_STATES), s_init, self.augment.initial])
        P0 = np.diag(np.concatenate([np.asarray(self.config.initial_state_std) ** 2, self.prior_log_std ** 2,
                                     self.augment.prior_std ** 2]))
        self.health.start = (x0.copy(), P0.copy())  # where a retempered start begins again
        self._init_filter(x0, P0)
        self.health.good = (self.x.copy(), self.P.copy())

    # -- hooks a variant implements ---------------------------------------------------------------
    @abc.abstractmethod
    def _init_filter(self, x0: np.ndarray, P0: np.ndarray) -> None:
        """Start the filter at mean ``x0`` (n_aug,) and covariance ``P0`` (n_aug, n_aug)."""

    @property
    @abc.abstractmethod
    def x(self) -> np.ndarray:
        """Augmented mean, shape (n_aug,) = (14 + extra states,)."""

    @property
    @abc.abstractmethod
    def P(self) -> np.ndarray:
        """Augmented covariance, shape (n_aug, n_aug)."""

    @abc.abstractmethod
    def _set(self, x: np.ndarray, P: np.ndarray) -> None:
        """Replace mean and covariance; abandons the current block."""

    @abc.abstractmethod
    def _propagate(self, dt: float, w: np.ndarray, speed: float) -> None:
        """Advance the mean by one step of ``dt`` [s] with the input ``w`` (4,) between its samples (the
        road-wheel angle's value and derivatives in normalised time, :mod:`online_id.model.intersample`; the
        hold's w is [δ, 0, 0, 0]) at the step's ``speed`` [m/s]."""

    @abc.abstractmethod
    def _observe(self, values: np.ndarray, mask: np.ndarray, delta: float, speed: float) -> None:
        """Gate this sample's measurements (``mask`` marks the usable ones) and add them to the block.

        Rejected channels are reported with ``self.health.count_outliers``.
        """

    @abc.abstractmethod
    def _flush(self) -> None:
        """Bring the covariance up to date with the samples propagated since the block started."""

    @abc.abstractmethod
    def _block_innovation(self):
        """After ``_flush``: (channels, block means z (m,), predicted means (m,), S (m, m)) or None."""

    @abc.abstractmethod
    def _apply_correction(self, keep: np.ndarray) -> None:
        """Update with the block means of the channels from ``_block_innovation`` where ``keep``."""

    def _close_block(self):
        """A variant's whole close of an ordinary block at once, its correction applied: (channels, ν, diag S), or
        None where it does not (the default): the health then takes ``_flush``, ``_block_innovation`` and
        ``_apply_correction`` one by one (filters/health.py ``correct``)."""
        return None

    @abc.abstractmethod
    def _start_block(self) -> None:
        """Forget the block's measurements; the next block starts at the current state."""

    # -- what the base works with ------------------------------------------------------------------
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
            return self.health.R_diag
        R = self.health.R_diag.copy()
        R[_VY] /= self._last_input[1] ** 2
        return R

    def _vy_scale(self) -> float:
        """What turns the lateral velocity's squared innovation, worked per unit speed, into SI: V² at the last sample
        (1 when the channel is not configured or no sample was worked)."""
        if self._last_input is None or not self._configured[_VY]:
            return 1.0
        return self._last_input[1] ** 2

    def _process_noise(self, elapsed: float) -> np.ndarray:
        """Diagonal of Q over ``elapsed`` seconds; also tallies the parameters' random-walk variance."""
        rw_sq = self._q_param
        self._random_walk_variance += rw_sq * elapsed
        key = (rw_sq, self._walk)  # (the rates change when the filter converges or stops learning: its _walk)
        if self._noise_rates is None or self._noise_rates[0] != rw_sq or self._noise_rates[1] is not self._walk:
            self._noise_rates = key + (np.concatenate([self._q_state, rw_sq * self._walk,
                                                       self.augment.random_walk_variance]),)
        q = self._noise_rates[2] * elapsed  # (the same numbers as each part times elapsed: _walk is 0 or 1)
        gap = self._gap_state_variance
        if not (type(gap) is float and gap == 0.0):
            q[:N_STATES] += gap
        self._gap_state_variance = 0.0
        return q

    _noise_rates = None  # (q_param, _walk, the diagonal of Q per second) of _process_noise

    @property
    def _q_param(self) -> float:
        """Random-walk variance per second of each log-scale parameter, now."""
        rw = self.config.parameter_random_walk if self.health.converged else self.config.converging_random_walk
        return rw ** 2

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
        except NUMERICAL_ERRORS:
            x, P = self.health.good
            self._set(x.copy(), P.copy())

    # -- reading the estimate ----------------------------------------------------------------------
    @property
    def events(self) -> Counter:
        """Counts of what happened: samples, corrections, gaps, outliers_rejected, resets, ..."""
        self._sync()
        return self._events

    @property
    def log_scale(self) -> np.ndarray:
        """Current log-scale parameters s, shape (8,)."""
        return self._parameter_mean().copy()

    def trace_values(self) -> tuple[np.ndarray, np.ndarray]:
        """(θ (8,), its 1σ (8,)) [SI] now: a trace row's values (online_id/estimation.py), the last ones again
        while :meth:`_estimate_arrays` are the same objects (a 100 Hz trace reads them at every sample; they
        change at corrections)."""
        key = self._estimate_arrays()
        cached = self._trace_cache
        if key is not None and cached is not None and all(a is b for a, b in zip(key, cached[0])):
            return cached[1], cached[2]
        theta = self.theta0 * np.exp(self.log_scale)
        values = (theta, theta * self.log_scale_std)
        # (the arrays themselves are kept, not their ids: a freed array's id may be reused)
        self._trace_cache = None if key is None else (key, *values)
        return values

    def _estimate_arrays(self):
        """Arrays that a variant replaces, never writes in place, whenever its parameters' mean or covariance
        changes (for :meth:`trace_values`), or None (the default: read them each time)."""
        return None

    _trace_cache = None

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
        return {c: float(np.sqrt(sq / n)) for c, sq, n in zip(MEASURED_CHANNELS, self.health.innovation_sq,
                                                               self.health.innovation_n) if n}

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
