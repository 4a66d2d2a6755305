"""The guards every online filter shares: what is done with a block's innovation, and whether the filter is well.

:class:`FilterHealth` is owned by an :class:`~online_id.filters.base.OnlineEstimator` (its ``health``) and acts on
it only through the filter's hooks (``x``, ``P``, ``_set``, ``_flush``, ``_block_innovation``,
``_apply_correction``, ``_start_block``) and its ``_restart_states``: the filter predicts and updates, this
decides (as Stone Soup's updater is handed a predictor, not written into it). At each correction it

- gates the block means against S (``FilterConfig.gate_sigma``) and counts what it rejects, per sample
  (:meth:`count_outliers`, called by the filter's ``_observe``) and per block;
- adapts R by covariance matching (:meth:`adapt_r`) and carries the tempering of R until the filter converged;
- checks the covariance (:meth:`check`) and resets to the last good state, retempers a start that ran away
  (:meth:`retemper`), holds the parameters at the prior once the filter diverged or the data show a sensor
  offset it does not estimate (:meth:`hold_at_prior`), reopens the covariance of a filter whose every block is
  rejected (:meth:`reopen`);
- judges convergence (:meth:`update_convergence`).
"""

from __future__ import annotations

import warnings
from collections import Counter

import numpy as np

from online_id.errors import DivergedWarning, SensorOffsetWarning
from online_id.filters import block_close
from online_id.filters.augment import N_AUG, PARAMS
from online_id.filters.config import MAX_RETEMPERS, RETEMPER_FACTOR, tempering_at
from online_id.filters.innovations import InnovationLog
from online_id.model.lateral import N_PARAMS, N_STATES
from online_id.stream.samples import MEASURED_CHANNELS

#: A log-scale parameter beyond ±this has left e^±5 = 0.007x-150x of its prior: no car is that far
#: from its constructor's figures, so the filter has diverged and is reset.
MAX_LOG_SCALE = 5.0
#: The lateral velocity's channel: worked per unit speed, its squared innovations back to SI by V² (``correct``).
_VY = MEASURED_CHANNELS.index("lateral_velocity")
#: The check's words for each of :func:`online_id.filters.block_close.state_fault`'s codes.
STATE_FAULTS = (None, "NaN or inf in the filter state", "non-positive variance", "parameter covariance exploded",
                "a parameter left the range 0.007x-150x of its prior")
#: The channels whose offsets a_y − V·r shows (filters/kinematics.py).
KINEMATIC_OFFSET_CHANNELS = ("lateral_acceleration", "yaw_rate")
#: Corrections between full positive-definiteness checks of P (a Cholesky): Joseph-form updates keep P
#: positive-definite, so a check every 50 catches round-off drift without paying one per correction.
FULL_CHECK_EVERY = 50
#: What a correction may raise on a broken covariance: the filter is reset, not the run ended.
NUMERICAL_ERRORS = (np.linalg.LinAlgError, FloatingPointError, ValueError)


#: A tempered filter whose every parameter σ is below this (log scale) and has fallen by less than PLATEAU_FALL
#: over PLATEAU_WINDOW_S, the parameters settled, has converged even above FilterConfig.converged_log_std: tempered
#: R and the converging random walk hold σ on a plateau that a logger's rate with an extra state puts just above
#: 0.03 (the built-in chirp at 100 Hz with accelerometer_gravity estimated: σ_b1 0.036-0.039 from 39 to 51 s,
#: converged at 58.6 s of 60; the second half judged tempered, INCONSISTENT in 6 of 14 seeds; issue 36).
PLATEAU_LOG_STD = 0.1
PLATEAU_FALL = 0.1
PLATEAU_WINDOW_S = 3.0


class FilterHealth:
    """The gating, R adaptation, health checks, resets and convergence of one filter ``est`` (see the module
    docstring). ``R_nominal``: the configured measurement noise variances (5,) [SI²], NaN for a channel not
    measured."""

    def __init__(self, est, R_nominal: np.ndarray):
        self.est = est
        config = est.config
        n_channels = len(MEASURED_CHANNELS)
        self.R_nominal = R_nominal
        #: the likelihood tempering until converged (FilterConfig.converging_r_scale at TEMPER_REFERENCE_RATE_HZ,
        #: scaled to the log's rate once its period is known: :meth:`scale_tempering`)
        self.temper = config.converging_r_scale
        self.R_diag = R_nominal * self.temper  # R now [SI²]: nominal × adaptation × tempering
        self.nis_mean = np.ones(n_channels)
        # sums of squared block innovations and their counts per channel (innovation_rms)
        self.innovation_sq, self.innovation_n = np.zeros(n_channels), np.zeros(n_channels)
        self.last_adapt_time: float | None = None
        #: the block innovations, normalised, for the consistency verdict (online_id.trust.consistency)
        self.innovations = InnovationLog()
        self.gated: Counter = Counter()  # rejected outliers per measured channel
        self.reset_reasons: Counter = Counter()
        self.converged = False
        self.settle_start = None
        self.plateau_start = None  # (t, s, σ) where the current plateau window began (update_convergence)
        self.converged_at: float | None = None
        #: when the filter diverged (config.diverged_resets resets within diverged_window_s), else None
        self.diverged_at: float | None = None
        #: why the parameters were held at the prior from ``diverged_at`` when not a divergence (None: diverged)
        self.held_because: str | None = None
        self.reset_times: list[float] = []
        #: said once: a_y − V·r shows an offset the filter does not estimate
        self.offset_told = any(st.group == "offsets" and st.key in KINEMATIC_OFFSET_CHANNELS
                               for st in est.augment.states)
        self.corrections_since_full_check = 0
        #: per measured channel, the time of the first of its blocks rejected in a row (NaN: its last was kept)
        self.rejecting_since = np.full(n_channels, np.nan)
        self.seen = np.zeros(n_channels, dtype=bool)  # channels with a sample in the open block
        self.start = None  # (x0, P0): where a retempered start begins again (retemper)
        self.good = None  # (x, P) after the last correction that passed the checks
        self.retempers = 0

    @property
    def r_temper(self) -> float:
        return 1.0 if self.converged else self.temper

    def scale_tempering(self, period: float) -> None:
        """The tempering for a log of this sample ``period`` [s] (:func:`~online_id.filters.config.tempering_at`,
        with the retemperings so far); R follows it until the filter converged."""
        temper = tempering_at(self.est.config.converging_r_scale, period) * RETEMPER_FACTOR ** self.retempers
        if not self.converged and temper != self.temper:
            self.R_diag = self.R_diag * (temper / self.temper)
        self.temper = temper

    def count_outliers(self, rejected: np.ndarray) -> None:
        """Count the channels of one sample that failed the outlier gate (``rejected`` (5,) bool)."""
        for i in np.flatnonzero(rejected):
            self.gated[MEASURED_CHANNELS[i]] += 1
            self.est._events["outliers_rejected"] += 1

    def count_outlier_totals(self, rejected: np.ndarray) -> None:
        """As :meth:`count_outliers` for several samples at once: ``rejected`` (5,) the count per channel."""
        for i in np.flatnonzero(rejected):
            self.gated[MEASURED_CHANNELS[i]] += int(rejected[i])
            self.est._events["outliers_rejected"] += int(rejected[i])

    # -- the correction ------------------------------------------------------------------------------
    def correct(self) -> None:
        """Close the block: the filter's block innovation, gated, R adapted, the update with what passed, then
        the checks."""
        est = self.est
        est._since_correction = 0
        checked = (None, None, None)  # (a state's fault code already found, for its x and P: see check)
        try:
            # an ordinary block's whole close, its correction applied, in one compiled call (filters/ekf.py)
            closed = est._close_block()
            if closed is None:
                est._flush()
                block = est._block_innovation()
                if block is None:
                    # nothing usable in this block: still check the filter (a broken covariance
                    # makes every sample fail its gate, and must not go unnoticed)
                    est._start_block()
                    if not self.listening(np.zeros(0, dtype=int)):
                        self.reopen()
                    self.check()
                    return
                channels, z, zp, S = block
                lost = self._booked_steps(channels, z - zp, S.diagonal())
            else:
                lost, checked = self._booked_close(*closed)
            if lost:
                self.reopen()
            if not self.offset_told:
                self.tell_offset()
        except NUMERICAL_ERRORS as exc:
            self.reset(f"{type(exc).__name__}: {exc}")
            return
        self.check(*checked)

    def _booked_steps(self, channels, nu, var) -> bool:
        """:meth:`correct`'s bookkeeping of a block taken step by step: the squared innovations (SI) and counts,
        the block's gate and the innovation log's row (the signed innovation in σ of S, and S's R against the
        nominal R: the adapted R hides misfit) in one compiled call, R adapted, the update with the channels that
        passed, the next block; returns whether the filter is lost (a channel unused too long)."""
        est = self.est
        innovations = self.innovations
        nis, keep = block_close.book_block(
            channels, nu, _as_compiled_takes(var), _VY, est._vy_scale(), self.innovation_sq, self.innovation_n,
            est.config.gate_sigma ** 2, innovations.next_row(), est._last_time, float(self.converged),
            self.R_diag, self.R_nominal)
        innovations.advance()
        self.adapt_r(channels, nis)
        if not keep.all():
            est._events["blocks_rejected"] += int(np.count_nonzero(~keep))
        if keep.any():
            est._apply_correction(keep)
            est._events["corrections"] += 1
        est._start_block()
        return not self.listening(channels[keep])

    def _booked_close(self, channels, nu, var) -> tuple[bool, tuple]:
        """:meth:`correct`'s bookkeeping of a block closed in one call (its correction applied, its every channel
        through the block's gate): as :meth:`_booked_steps`, with the state's fault tests, in one compiled call
        (``block_close.book_adapt_listen``), then the next block. Returns whether the filter is lost and the
        check's (fault code, x, P)."""
        est = self.est
        config = est.config
        w = self._adapt_weight()
        innovations = self.innovations
        x, P = est.x, est.P  # (the corrected state: the check's tests in the same call)
        _, longest, fault = block_close.book_adapt_listen(
            channels, nu, _as_compiled_takes(var), _VY, est._vy_scale(), self.innovation_sq, self.innovation_n,
            config.gate_sigma ** 2, innovations.next_row(), est._last_time, float(self.converged), self.R_diag,
            self.R_nominal, w is not None, self.nis_mean, self.r_temper, 0.0 if w is None else w,
            1.0 if self.converged else self.temper, self.seen, self.rejecting_since, x, P, est._free_aug,
            PARAMS.start, PARAMS.stop - PARAMS.start, config.max_parameter_std ** 2, MAX_LOG_SCALE)
        innovations.advance()
        est._events["corrections"] += 1
        est._start_block()
        return longest >= config.reopen_after_s, (fault, x, P)

    def _adapt_weight(self) -> float | None:
        """The weight of this correction in R's running means, min(1, Δt/τ) since the last one (whose time it
        moves on), or None where adaptation is off (``adaptive_r_window_s`` ≤ 0)."""
        tau = self.est.config.adaptive_r_window_s
        t = self.est._last_time
        dt = 0.0 if self.last_adapt_time is None else t - self.last_adapt_time
        self.last_adapt_time = t
        return None if tau <= 0 else min(1.0, dt / tau)

    def adapt_r(self, channels: np.ndarray, nis: np.ndarray) -> None:
        """Covariance matching: R_i = R_nominal_i · max(1, running mean of channel i's NIS).

        The NIS of a sample is clipped at the gate so that a rejected spike moves the mean
        by at most one gate's worth.
        """
        w = self._adapt_weight()
        if w is None:
            return
        config = self.est.config
        # nis_mean ← nis_mean + w (min(NIS · R/R_nominal / r_temper, gate²) − nis_mean), R ← R_nominal max(1, nis_mean)
        # (× the tempering until converged), channel by channel in one compiled call
        block_close.adapt_r(nis, channels, self.R_diag, self.R_nominal, self.nis_mean, self.r_temper,
                            config.gate_sigma ** 2, w, 1.0 if self.converged else self.temper)

    # -- health ----------------------------------------------------------------------------------------
    def check(self, fault: int | None = None, x=None, P=None) -> None:
        """After a correction: reset on a broken mean or covariance, else keep it as the last good state and
        judge convergence. ``fault``: the state's fault code already found for ``x``, ``P`` (the one-call close's
        bookkeeping: ``block_close.book_adapt_listen``)."""
        est = self.est
        if fault is None:
            x, P = est.x, est.P
            # (the tests in one compiled call, in this order; a fixed parameter's variance is 0 by design)
            fault = block_close.state_fault(x, P, est._free_aug, PARAMS.start, PARAMS.stop - PARAMS.start,
                                            est.config.max_parameter_std ** 2, MAX_LOG_SCALE)
        diag = P.diagonal()
        bad = STATE_FAULTS[fault]
        if not bad:
            self.corrections_since_full_check += 1
            if self.corrections_since_full_check >= FULL_CHECK_EVERY:
                self.corrections_since_full_check = 0
                try:
                    np.linalg.cholesky(P[np.ix_(est._free_aug, est._free_aug)])
                except np.linalg.LinAlgError:
                    bad = "covariance not positive-definite"
        if bad:
            self.reset(bad)
            return
        self.good = (x.copy(), P.copy())
        self.update_convergence(x[PARAMS], np.sqrt(diag[PARAMS]))

    def update_convergence(self, s: np.ndarray, sd: np.ndarray) -> None:
        """Converged: every σ below ``converged_log_std`` and no parameter moved more than its σ
        since the start of the current ``settle_window_s`` window; or every σ below :data:`PLATEAU_LOG_STD` and
        no longer falling (:meth:`plateaued`). Once converged, stays so."""
        if self.converged:
            return
        t = self.est._last_time
        config = self.est.config
        if sd.max() >= config.converged_log_std:
            self.settle_start = None
            if self.plateaued(t, s, sd):
                self.converged = True
                self.converged_at = t
                self.R_diag = self.R_diag / self.temper
            return
        if self.settle_start is None:
            self.settle_start = (t, s.copy())
            return
        t0, s0 = self.settle_start
        if np.any(np.abs(s - s0) > sd):
            self.settle_start = (t, s.copy())
        elif t - t0 >= config.settle_window_s:
            self.converged = True
            self.converged_at = t
            self.R_diag = self.R_diag / self.temper

    def plateaued(self, t: float, s: np.ndarray, sd: np.ndarray) -> bool:
        """Every σ below :data:`PLATEAU_LOG_STD` and informed (under ``config.uninformed_ratio`` of its prior σ),
        the parameters settled (none moved more than its σ) and no σ fallen
        by :data:`PLATEAU_FALL` or more over the last :data:`PLATEAU_WINDOW_S`: the tempered filter has learned
        what it can while tempered (its forgetting holds σ up), and waiting for ``converged_log_std`` would judge
        and report a tempered filter."""
        est = self.est
        free = est._free_aug[PARAMS]
        if sd.max() >= PLATEAU_LOG_STD or np.any(sd[free] >= est.config.uninformed_ratio * est.prior_log_std[free]):
            # (wide, or a parameter the data have not informed: a run without excitation sits on its prior's σ,
            # which is no plateau of learning)
            self.plateau_start = None
            return False
        if self.plateau_start is None:
            self.plateau_start = (t, s.copy(), sd.copy())
            return False
        t0, s0, sd0 = self.plateau_start
        if np.any(np.abs(s - s0) > sd):  # still moving: a new window
            self.plateau_start = (t, s.copy(), sd.copy())
            return False
        if t - t0 < PLATEAU_WINDOW_S:
            return False
        if np.all(sd > (1.0 - PLATEAU_FALL) * sd0):
            return True
        self.plateau_start = (t, s.copy(), sd.copy())  # still falling: measure the next window
        return False

    def reset(self, why: str) -> None:
        """Back to the last good state, the model states restarted; a burst of resets retempers or diverges."""
        est = self.est
        est._events["resets"] += 1
        self.reset_reasons[why] += 1
        if self.reset_reasons[why] == 1:  # warn once per cause; the rest are counted
            warnings.warn(f"{est.name}: {why} at t = {est._last_time:.3f} s; reset to the last good state"
                          " (further resets for this cause are counted, not shown)", RuntimeWarning, stacklevel=3)
        x, P = self.good
        est._set(x.copy(), P.copy())
        self.corrections_since_full_check = 0
        est._restart_states()
        window = est.config.diverged_window_s
        self.reset_times = [t for t in self.reset_times if est._last_time - t < window] + [est._last_time]
        if self.diverged_at is None and len(self.reset_times) >= est.config.diverged_resets:
            # (a sensor offset that a_y − V·r shows is not cured by starting again: --offsets is; it diverges)
            if not self.converged and self.retempers < MAX_RETEMPERS and self.kinematic_offset() is None:
                self.retemper()
            else:
                self.diverge()

    def retemper(self) -> None:
        """Resets in a burst before the filter converged: it learned faster than this log's fit to the model
        allows (the tempering is scaled to the rate for a log the model fits; the race car's, biased and past
        the model, ran its b1 to 1 % of the prior in 3 s at 100 Hz). Start the 8 parameters again from the prior
        (the extra states keep their values, with their prior variances back) with the tempering
        ×:data:`RETEMPER_FACTOR` (at most :data:`MAX_RETEMPERS` times; then the filter has diverged). Not when
        a_y − V·r shows a sensor offset the filter does not estimate (the filter then holds its parameters at the
        prior when it sees it, and the verdict points to --offsets). Counted as ``retempered``, said once."""
        est = self.est
        self.retempers += 1
        est._events["retempered"] += 1
        old = self.temper
        self.temper = old * RETEMPER_FACTOR
        self.R_diag = self.R_diag * RETEMPER_FACTOR
        warnings.warn(f"{est.name}: {len(self.reset_times)} resets within {est.config.diverged_window_s:g} s up to"
                      f" t = {est._last_time:.3f} s before converging: the parameters start again from the prior,"
                      f" tempered {self.temper:g}x (was {old:g}x); this log fits the model less well than a clean"
                      " run", RuntimeWarning, stacklevel=4)
        self.reset_times = []
        est._flush_quiet()
        x0, P0 = self.start
        x, P = est.x.copy(), est.P.copy()
        x[PARAMS] = x0[PARAMS]  # (the extra states keep their values, with their prior variance back: a μ or an
        # offset learned is kept; the 8 are what ran away)
        P[N_STATES:, :] = 0.0
        P[:, N_STATES:] = 0.0
        P[N_STATES:, N_STATES:] = P0[N_STATES:, N_STATES:]
        est._set(x, P)
        self.good = (x.copy(), P.copy())
        self.settle_start = self.plateau_start = None
        est._restart_states()

    def diverge(self) -> None:
        """Resets in a burst: the filter has diverged. Stop learning the parameters (they go back to the
        prior, with no variance inside the filter so that they stay there), keep filtering the model states
        and the extra states; the estimate reads as the prior with the prior's σ, not informed."""
        est = self.est
        est._events["diverged"] = 1
        warnings.warn(f"{est.name}: {len(self.reset_times)} resets within {est.config.diverged_window_s:g} s up to"
                      f" t = {est._last_time:.3f} s: the filter diverged; its parameters are no longer learned"
                      " (held at the prior, reported with the prior's σ, not informed)", DivergedWarning, stacklevel=4)
        self.hold_at_prior()

    def hold_at_prior(self) -> None:
        """Stop learning the parameters: back to the prior, no variance inside the filter (they stay there),
        reported at the prior with the prior's σ, not informed (``diverged_at``, :attr:`held_because`)."""
        est = self.est
        self.diverged_at = est._last_time
        est._fixed = np.ones(N_PARAMS, dtype=bool)
        est._walk = np.zeros(N_PARAMS)
        est._free_aug = est._free_aug.copy()
        est._free_aug[PARAMS] = False
        est._flush_quiet()
        x, P = est.x.copy(), est.P.copy()
        x[PARAMS] = 0.0
        P[PARAMS, :] = 0.0
        P[:, PARAMS] = 0.0
        est._set(x, P)
        self.good = (x.copy(), P.copy())
        est._restart_states()

    def listening(self, kept: np.ndarray) -> bool:
        """Track, per channel measured in the block just closed, whether the correction used it (``kept``: its
        index; a channel whose samples all failed the outlier gate, or whose block failed the block gate, was
        not). False when some channel has not been used for ``config.reopen_after_s``: the filter is lost."""
        # (used, or not measured: no streak; else the streak's start, NaN until one starts; in one compiled call)
        longest = block_close.listen(self.seen, np.asarray(kept, dtype=np.int64), self.rejecting_since,
                                     float(self.est._last_time))
        return not longest >= self.est.config.reopen_after_s

    def reopen(self) -> None:
        """The gate has rejected a channel's every block for ``config.reopen_after_s``: the filter is lost.
        Raise the parameters' and extra states' variances back to a fraction of their prior's, forget their
        correlations, restart the model states."""
        est = self.est
        config = est.config
        est._events["reopened"] += 1
        if est._events["reopened"] == 1:
            lost = [c for c, t in zip(MEASURED_CHANNELS, self.rejecting_since)
                    if est._last_time - t >= config.reopen_after_s]
            warnings.warn(f"{est.name}: every correction from {', '.join(lost)} rejected for"
                          f" {config.reopen_after_s:g} s up to t = {est._last_time:.3f} s: the estimate is lost;"
                          " its covariance is reopened (further reopenings are counted, not shown)",
                          RuntimeWarning, stacklevel=3)
        self.rejecting_since[:] = np.nan
        est._flush_quiet()
        x, P = est.x.copy(), est.P.copy()
        prior = np.concatenate([est.prior_log_std ** 2, est.augment.prior_std ** 2]) * config.reopen_fraction
        var = np.maximum(np.diag(P)[N_STATES:], prior)
        var[:N_AUG - N_STATES][est._fixed] = 0.0
        P[N_STATES:, :] = 0.0
        P[:, N_STATES:] = 0.0
        P[N_STATES:, N_STATES:] = np.diag(var)
        est._set(x, P)
        est._restart_states()

    # -- sensor offsets the filter does not estimate -------------------------------------------------------
    def tell_offset(self) -> None:
        """Warn once, as soon as a_y − V·r shows an offset the filter does not estimate (the default run):
        the filter cannot learn what the model cannot produce, and may break down trying."""
        est = self.est
        excess = est.kinematics.offset()
        if excess is None:
            return
        self.offset_told = True
        k = est.kinematics
        hold = self.diverged_at is None and not any(st.group == "offsets" for st in est.augment.states)
        warnings.warn(f"{est.name}: a_y − V·r averages {excess:+.3g} m/s² over the first {k.duration:.1f} s, beyond"
                      f" the ±{max(k.bound, 0):.2g} m/s² any car's sideslip allows: a sensor offset on"
                      f" lateral_acceleration ({excess:+.3g} m/s²) or yaw_rate ({-excess / k.mean_speed:+.3g} rad/s);"
                      + (" the parameters are no longer learned (held at the prior: what they learned from biased"
                         " data is not the car);" if hold else "")
                      + " --offsets estimates both", SensorOffsetWarning, stacklevel=4)
        if hold:  # (with the cubic between samples the biased run no longer broke the filter: it ran to Mzz 51x,
            # "informed"; issue 36)
            est._events["held_for_offset"] = 1
            self.held_because = (f"a_y − V·r showed a sensor offset the filter does not estimate at t ="
                                 f" {est._last_time:.1f} s")
            self.hold_at_prior()

    def kinematic_offset(self) -> float | None:
        """The mean of a_y − V·r over the run less what the estimated offsets explain, when beyond what the
        dynamics allow (filters/kinematics.py), else None [m/s²]."""
        est = self.est
        expected = 0.0
        if est.augment:
            x = est.x
            for i, st in enumerate(est.augment.states):
                if st.group == "offsets" and st.key == "lateral_acceleration":
                    expected += float(x[N_AUG + i])
                elif st.group == "offsets" and st.key == "yaw_rate":
                    expected -= float(x[N_AUG + i]) * est.kinematics.mean_speed
        return est.kinematics.offset(expected)


class HealthReadings:
    """What the estimator's :class:`FilterHealth` (``self.health``) decided, read from the estimator."""

    @property
    def converged_at(self) -> float | None:
        """When the filter converged [s], else None."""
        return self.health.converged_at

    @property
    def diverged_at(self) -> float | None:
        """When the filter diverged (``config.diverged_resets`` resets within ``diverged_window_s``) or its
        parameters were held at the prior (:attr:`held_because`), else None."""
        return self.health.diverged_at

    @property
    def held_because(self) -> str | None:
        """Why the parameters were held at the prior from :attr:`diverged_at` when not a divergence (None: diverged)."""
        return self.health.held_because

    @property
    def reset_reasons(self) -> Counter:
        """Resets to the last good state, by cause."""
        return self.health.reset_reasons

    @property
    def innovations(self) -> InnovationLog:
        """The block innovations, normalised, for the consistency verdict (online_id.trust.consistency)."""
        return self.health.innovations

    @property
    def _R_diag(self) -> np.ndarray:
        """The measurement noise variances (5,) now [SI²]: nominal, adapted, tempered."""
        return self.health.R_diag

    def kinematic_offset(self) -> float | None:
        """The mean of a_y − V·r over the run less what the estimated offsets explain, when beyond what the
        dynamics allow (filters/kinematics.py), else None [m/s²]."""
        return self.health.kinematic_offset()

    @property
    def gated(self) -> Counter:
        """Rejected outliers per measured channel."""
        self._sync()
        return self.health.gated


def _as_compiled_takes(var: np.ndarray) -> np.ndarray:
    """S's diagonal (a read-only view, strided) as the compiled bookkeeping takes it: a writable contiguous copy,
    the type :func:`~online_id.filters.block_close.compile_now` warms. numba compiles a function once for each type
    of array it is given (a second compile of ``book_adapt_listen`` on a first run otherwise)."""
    return np.array(var, dtype=float)
