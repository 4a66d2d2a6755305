"""Settings of the online estimators, with defaults and their reasons."""

from __future__ import annotations

from dataclasses import dataclass, field

from online_id.model.intersample import DEFAULT_INTERSAMPLE, check_kind
from online_id.units import G

#: Standard gravity [m/s²].
#: Default linear range of the model [m/s²]: Haro ran his tests under 0.4 g because his tyres are
#: linear (MODEL.md, "Test protocol"); the limit sits a margin above that so a run made by his
#: protocol keeps every sample (the built-in run peaks at 0.40 g, plus sensor noise), while the
#: cornering of a car driven at 1-1.7 g is left out.
LINEAR_RANGE_AY = 0.5 * G
#: With saturating tyres (tire_saturation): samples with |a_y| beyond this multiple of μ̂·g are beyond what
#: the tanh law can make (its total peak force is μ·M·g; roll acceleration and noise add up to ~15 % on a
#: clean run at the limit) and are not learned from (filters/tyre_filters.py).
TYRE_RANGE = 1.25


def _default_measurement_std() -> dict[str, float]:
    # The simulator's default sensor noise (MODEL.md, "Accuracy limit"); the lateral velocity's an INS's or an
    # optical sensor's (0.014-0.03 m/s RMS in their data sheets; issue 38)
    return {"yaw_rate": 0.004, "roll_angle": 0.0005, "roll_rate": 0.004, "lateral_acceleration": 0.05,
            "lateral_velocity": 0.02}


#: Seconds of consecutive rejected blocks after which the filter reopens its covariance (FilterConfig).
REOPEN_AFTER_S = 3.0
#: Fraction of the prior variance the parameters get back when the filter reopens.
REOPEN_FRACTION = 0.25
#: The longest a correction's block may span [s]. A block's correction relates its mean to the state at its
#: start through the model linearised at the parameters of that moment; over a long block a parameter error
#: grows into the prediction faster than the linearisation follows (issue 36: at 100 Hz a 0.2 s block made the
#: true model's innovations 1.9x their size, 0.1 s 1.2x; 0.2 s diverged once the tempering was scaled to the
#: rate). 50 ms keeps the default 20 samples at 1 kHz and is a fifth of the chirp's shortest period (4 Hz):
#: 10 samples at 200 Hz, 5 at 100 Hz (the race car), 4 at 83 Hz (the RAV4), 2 at 50 Hz, 1 at 25 Hz and below.
MAX_BLOCK_S = 0.05
#: The UKF's: 20 ms, a block's span at 1 kHz. With 50 ms its σ fell late and the true model read as 1.2-1.5x
#: its innovations at 50, 100 and 200 Hz (7 of 9 runs, the built-in chirp simulated at 10 kHz, 3 seeds a rate);
#: with 20 ms (1, 2, 4 samples) every run consistent, worst parameter 0.9 % (issue 36).
UKF_MAX_BLOCK_S = 0.02
#: The rate at which FilterConfig.converging_r_scale is the tempering [Hz]: the filter learns from f/(R·scale)
#: samples' worth a second while it converges, so a log at rate f is tempered by scale·f/1000 (at least 1): the
#: same information a second at every rate. Unscaled, 300 held a 100 Hz log's σ above converged_log_std for the
#: whole 60 s run (never converged: the verdict judged a tempered filter, 1.9x; issue 36).
TEMPER_REFERENCE_RATE_HZ = 1000.0


def tempering_at(scale: float, period: float) -> float:
    """The tempering of R for a log of sample ``period`` [s]: ``scale`` at :data:`TEMPER_REFERENCE_RATE_HZ`, in
    proportion to the rate, at least 1."""
    return max(1.0, scale / (TEMPER_REFERENCE_RATE_HZ * period))
#: A time step longer than this many sample periods restarts the model states, whatever max_gap_s says:
#: at 10 Hz the 0.1 s restart threshold equals the period itself (the EKF then restarted at 375 of 600
#: steps and never corrected). 2.5, as the track-run reader's gaps (online_id.io.tracklog.GAP_FACTOR).
RESTART_PERIODS = 2.5

#: Resets within DIVERGED_WINDOW_S after which the filter has diverged (FilterConfig.diverged_resets): a
#: clean run has none, the race car's 400 s at 1.7 g had 15 spread over the run before the block update
#: changed (0 now); a 0.3 m/s² a_y offset without --offsets broke the filter 18 times a second (1,060 resets,
#: Mzz 73x, "informed" on every parameter).
DIVERGED_RESETS = 5
DIVERGED_WINDOW_S = 10.0
#: Before it has converged, a burst of resets starts the filter again from the prior tempered this much more,
#: at most MAX_RETEMPERS times (FilterHealth.retemper); after that, or once converged, it has diverged. The
#: rate-scaled tempering learns as fast a second at 100 Hz as at 1 kHz: right for a log the model fits, too
#: fast for the race car's (issue 36: its b1 at 1 % of the prior in 3 s), which the old unscaled 300 held.
RETEMPER_FACTOR = 10.0
MAX_RETEMPERS = 1


@dataclass(frozen=True)
class FilterConfig:
    """How an augmented-state filter runs.

    Attributes
    ----------
    correct_every : correct every k-th sample with the block means of the k samples (at most ``max_block_s``
        of them: k shrinks on a slow log, to 1 at 5 Hz and below), predicting
        every sample (Macchi's "filter every few integration steps"; block means keep nearly all
        the information). 20 at 1 kHz = 50 corrections/s. Measured on the built-in 80 km/h run
        against k = 10: final σ about 3 % wider, errors against truth unchanged (0.151 % against
        0.140 % at worst; 60 km/h 0.086 % against 0.096 %), the EKF about 1.6x faster.
    converging_r_scale : measurement variance × this until converged (likelihood tempering). From a
        far start the early low-frequency data admit wrong branches (a soft roll spring traded for
        heavy damping); tempered corrections keep the filter from committing before the data
        separate them. Measured on the 80 km/h chirp from 0.5× truth: untempered EKF 73 % off,
        × 10 within 0.06 %; without roll, × 100 → 2.2 %, × 300 → 0.6 %. This is the factor at 1 kHz; a log at
        another rate is tempered in proportion to its rate (:func:`tempering_at`: 30 at 100 Hz, 7.5 at 25 Hz).
    settle_window_s : converged also needs every parameter to have moved less than its own σ over
        this window: a small σ alone can hide a parameter still sliding towards its value.
    converged_log_std : the filter counts as converged (tempering and forgetting end) once every
        parameter's log-scale σ is below this and the parameters have settled (settle_window_s).
    measurement_std : 1σ of each measured channel [SI units], the diagonal of R.
    parameter_random_walk : 1σ growth of each log-scale parameter per √s (random-walk process noise).
    converging_random_walk : the same while not yet converged (see converged_log_std): forgetting
        what the first seconds of a run taught with wrong neighbours keeps early, weakly informed
        parameters (Mzz and b1 under 1 Hz) from locking on a wrong value.
    state_process_std : 1σ per √s of the noise driving the 6 model states
        [rad/s, rad, rad, rad/s, rad, rad] (model error the filter may absorb).
    initial_state_std : 1σ of the initial model states (the car may be turning when the run starts).
    prior_log_std_floor : the prior's relative standard errors are widened to at least this
        (log-scale σ): the track car lies up to 4 constructor σ away (Kro, MODEL.md).
    p0_scale : multiplies the initial parameter variance (Macchi's initial-variance study).
    min_speed_mps : below this speed parameter updates freeze (the model divides by V).
    gate_sigma : a channel whose innovation exceeds this many σ of its predicted spread is
        rejected for that correction and counted as an outlier.
    max_gap_s : a time step longer than this (and than :data:`RESTART_PERIODS` sample periods) is a
        dropout: the model states restart from their initial uncertainty, the parameters are kept.
    max_block_s : the longest span of a correction's block [s]; None (the default): the filter's own,
        :data:`MAX_BLOCK_S` for the EKF, :data:`UKF_MAX_BLOCK_S` for the UKF.
    max_bridged_samples : every step that skipped samples (up to max_gap_s) is bridged with δ
        interpolated across it (online_id/stream/gaps.py); after a longer run of missing samples
        than this the model states also forget part of what they knew (their initial variance ×
        gap / max_gap_s), since a linear δ no longer describes a gap that long. Measured on a 20 s
        chirp with 20 % lost: bursts up to 20 samples bridge within 1.8 σ of the full log's
        estimate; bursts of 60 were 9.5 σ off when only bridged, 2.8 σ with the forgetting.
    speed_tolerance : relative distance of the speed from the linearisation speed that triggers a new
        linearisation; within it the steps are corrected to first order in the speed difference
        (filters/local_model.py: error under 2e-4 of a step's Φ − I at 0.02, less than the speed
        sensor's own 0.1-0.5 % moves it). 0.02 relinearises about every 25 samples on the race-car
        log (16-61 m/s at 100 Hz) instead of at nearly every sample at 1e-3; a new point for speed
        alone does not end the EKF's group of samples (filters/ekf.py).
    adaptive_r_window_s : time constant [s] of the running mean of each channel's normalised
        innovation squared; while it exceeds 1 the model is not yet consistent with the data
        and that channel's R is inflated by it (covariance matching). 0 switches this off.
    relinearise_log_step : a log-scale parameter change that triggers a new discretisation; below
        it the last one is corrected to first order in the change (error O(step²), about 1e-5 at
        3e-3, two orders below the parameters' σ). 3e-3 rebuilds 416 times on the built-in run
        against 987 at 1e-3, with the same errors against truth to 0.001 %.
    uninformed_ratio : a parameter whose final σ is above this fraction of its initial σ is
        flagged "not informed" by the data.
    max_parameter_std : a log-scale σ above this (a covariance explosion) triggers a reset.
    linear_range_ay : samples whose measured |a_y| exceeds this [m/s²] are propagated but not
        learned from (counted as ``outside_linear_range``): the model's tyres are linear (default 0.5 g,
        see :data:`LINEAR_RANGE_AY`). inf: no limit. Not used with saturating tyres (``tire_saturation``).
    reopen_after_s : when the gate has rejected every block of a channel for this long [s], the filter is
        lost (its parameters sit where that channel keeps contradicting them, each rejection keeping them
        there): the parameters' and extra states' variances are raised back to ``reopen_fraction`` of their
        prior variance (cross-covariances dropped) and the model states restarted, counted as ``reopened``.
        inf: never. A clean run never rejects for that long (:data:`REOPEN_AFTER_S`).
    diverged_resets, diverged_window_s : this many resets within this many seconds [s] and the filter has
        diverged: resetting to the last good state no longer helps (that state is already on the way out).
        From then on its parameters are not learned: they are held at the prior and reported with the
        prior's σ as not informed, never as a confident wrong answer (``diverged`` event, a warning, a
        reason in the verdict). inf resets: never (:data:`DIVERGED_RESETS`).
    intersample : the steering angle and the speed between two samples (:mod:`online_id.model.intersample`):
        ``"cubic"`` as a logger sees a continuous car, ``"linear"``, or ``"hold"`` (zero-order hold).
    tyre_range : with saturating tyres, samples whose |a_y| exceeds ``tyre_range``·(μ̂ + 3σ_μ)·g are not learned
        from (``outside_model_range``; :data:`TYRE_RANGE`)
    """

    correct_every: int = 20
    converging_r_scale: float = 300.0
    converged_log_std: float = 0.03
    settle_window_s: float = 2.0
    measurement_std: dict[str, float] = field(default_factory=_default_measurement_std)
    parameter_random_walk: float = 1e-4
    converging_random_walk: float = 3e-3
    state_process_std: tuple[float, ...] = (1e-3, 1e-4, 1e-5, 1e-3, 1e-4, 1e-4)
    initial_state_std: tuple[float, ...] = (0.05, 0.01, 0.01, 0.05, 0.01, 0.01)
    prior_log_std_floor: float = 1.0
    p0_scale: float = 1.0
    min_speed_mps: float = 3.0
    gate_sigma: float = 5.0
    max_gap_s: float = 0.1
    max_block_s: float | None = None
    max_bridged_samples: int = 20
    speed_tolerance: float = 0.02
    relinearise_log_step: float = 3e-3
    adaptive_r_window_s: float = 0.5
    uninformed_ratio: float = 0.5
    max_parameter_std: float = 5.0
    linear_range_ay: float = LINEAR_RANGE_AY
    tyre_range: float = TYRE_RANGE
    reopen_after_s: float = REOPEN_AFTER_S
    reopen_fraction: float = REOPEN_FRACTION
    diverged_resets: float = DIVERGED_RESETS
    diverged_window_s: float = DIVERGED_WINDOW_S
    intersample: str = DEFAULT_INTERSAMPLE

    def __post_init__(self):
        check_kind(self.intersample)
        if self.correct_every < 1:
            raise ValueError("correct_every must be at least 1")
        if self.min_speed_mps <= 0:
            raise ValueError("min_speed_mps must be positive")
        if not self.reopen_after_s > 0 or not 0 < self.reopen_fraction <= 1:
            raise ValueError("reopen_after_s must be positive and reopen_fraction in (0, 1]")
        if self.max_block_s is not None and not self.max_block_s > 0:
            raise ValueError("max_block_s must be positive")
        if not self.tyre_range > 0:
            raise ValueError("tyre_range must be positive")
        if not self.linear_range_ay > 0:
            raise ValueError("linear_range_ay must be positive")
        for name, sd in self.measurement_std.items():
            if not sd > 0:
                raise ValueError(f"measurement_std[{name!r}] must be positive")
