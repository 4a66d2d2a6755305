"""A log sampled slowly (10 Hz): every threshold in time scales with the log's own period (issue 30).

Before: the EKF restarted its states at 375 of the 600 steps of a 10 Hz run (the 0.1 s restart threshold
equalled the period) and never corrected; ``check`` measured a "noise floor" from second differences that
at 10 Hz is the signal itself (a_y 1.8 m/s² against 0.05) and said Mzz and Mxx could not be determined by
any estimator, while the fit and the polish got Mzz within 0.03 %.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from online_id.batchfit.cost import FitCost
from online_id.batchfit.polish import POLISH_BURN_IN_S, polish_estimate
from online_id.estimation import make_estimator, run_estimator
from online_id.filters import FilterConfig
from online_id.sim.simulator import simulate
from online_id.stream.gaps import SampleClock
from online_id.stream.samples import block_samples, samples_from_run
from online_id.trust.check import check_run, noise_floor
from online_id.vehicle import PARAMETER_NAMES, load_vehicle

CAR = load_vehicle("haro2008")
FOUR_CHANNELS = ("yaw_rate", "roll_angle", "roll_rate", "lateral_acceleration")
TRUTH = CAR.truth("track")
#: The filter alone at 10 Hz: it never converges in 60 s (100x less information than at 1 kHz keeps it
#: tempered), so its σ is wide (4-17 %) and honest: within 3σ and 10 % of the truth. The polish after it
#: reaches the Cramér-Rao scale: within 1 %.
FILTER_TOLERANCE, FILTER_SIGMAS, POLISHED_TOLERANCE = 0.10, 3.0, 0.01


#: A 10 Hz log cannot carry the built-in chirp's top (4 Hz is 80 % of its Nyquist frequency): no curve through
#: its samples follows it (integrated at 10 kHz and logged at 10 Hz, the cubic filter gave Mzz −17 %, 26σ;
#: issue 36 is right at 25 Hz and above). What these tests are about is the thresholds in time, so the run is
#: the model's own discretisation at 10 Hz, the steering held over each sample, and every job takes the hold.
SLOW = "hold"


@pytest.fixture(scope="module")
def slow_run():
    return simulate(CAR, TRUTH, duration_s=60.0, rate_hz=10.0, seed=3, integration_rate_hz=None).run


def test_the_filter_corrects_a_10_hz_log_without_spurious_gaps(slow_run):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no reset, no warning of any kind on a clean slow run
        res = run_estimator(make_estimator(CAR, "ekf", config=FilterConfig(intersample=SLOW)),
                            samples_from_run(slow_run))
    events = res.events
    assert events.get("gaps", 0) == 0 and events.get("missing_samples", 0) == 0, events
    # a block spans at most FilterConfig.max_block_s: 2 samples at 10 Hz (not 20 = 2 s)
    assert events["corrections"] >= (len(slow_run) - 1) // 2 - 1, events
    errors = res.parameters.to_vector() / TRUTH.to_vector() - 1
    z = (res.parameters.to_vector() - TRUTH.to_vector()) / res.std
    report = ", ".join(f"{n} {100 * e:+.2f}% ({s:+.1f}σ)" for n, e, s in zip(PARAMETER_NAMES, errors, z))
    assert np.all(np.abs(errors) < FILTER_TOLERANCE) and np.all(np.abs(z) < FILTER_SIGMAS), report
    assert res.consistency["judged"] and res.consistency["consistent"], res.consistency["reasons"]
    assert polish_estimate(res, CAR, slow_run, FilterConfig().measurement_std, burn_in_s=POLISH_BURN_IN_S,
                           intersample=SLOW) is None
    polished = res.parameters.to_vector() / TRUTH.to_vector() - 1
    assert np.all(np.abs(polished) < POLISHED_TOLERANCE), polished


def test_the_clock_knows_a_slow_period_from_its_first_steps():
    clock = SampleClock()
    for _ in range(4):
        clock.observe(0.1 + 1e-12)
    assert clock.rough_period == pytest.approx(0.1)  # not after 64 steps (6.4 s at 10 Hz)
    assert clock.period is None  # missing samples are judged against a full window only


def test_check_says_what_the_estimators_reach_at_10_hz(slow_run):
    rep = check_run(slow_run, CAR, intersample=SLOW)
    assert rep.not_determined == [], (rep.not_determined, rep.advice)
    assert set(rep.noise_floor) == set(FOUR_CHANNELS)  # (the channels the log has)
    for c, floor in rep.noise_floor.items():  # the log's noise is the simulator's (the configured), not the signal
        assert floor == pytest.approx(rep.noise_std[c], rel=0.3), rep.noise_floor
    assert rep.decisive.crlb_relative_std[PARAMETER_NAMES.index("Mzz")] < 0.02
    # the second difference alone sees the signal: that was the bug
    assert noise_floor(slow_run.lateral_acceleration) > 10 * rep.noise_std["lateral_acceleration"]


def test_the_candidate_chirp_stays_below_a_slow_logs_nyquist_frequency():
    from online_id.trust.check import chirp_band

    assert chirp_band(1000.0) == (0.2, 4.0) and chirp_band(10.0) == (0.2, 4.0)
    assert chirp_band(5.0) == (0.2, pytest.approx(2.0))


def test_batch_blocks_never_span_more_than_a_tenth_of_a_second(slow_run):
    assert block_samples(0.001, 10) == 10 and block_samples(0.01, 10) == 10 and block_samples(0.1, 10) == 1
    assert FitCost(CAR, slow_run, CAR.prior.to_vector()).sim.q == 1


def test_resampling_a_10_hz_log_is_not_a_dropout(slow_run):
    from online_id.drivers.resample import resample_run

    jittered = slow_run.slice(0, len(slow_run))
    jittered.time = jittered.time + np.random.default_rng(0).uniform(0, 0.004, len(jittered))
    out, info = resample_run(jittered, 10.0)
    assert info["samples"] >= len(slow_run) - 1


def test_a_10_hz_can_message_is_not_stale_between_its_frames():
    import can
    from online_id.drivers.assembler import FrameAssembler
    from online_id.drivers.can_log import load_dbc
    from online_id.drivers.signal_map import builtin_dbc_path, load_signal_map

    assembler = FrameAssembler(load_dbc(builtin_dbc_path()), load_signal_map("online_id"))
    message = assembler.map.trigger
    frame_id = next(i for i, m in assembler._messages.items() if m.name == message)
    for k in range(20):  # the trigger message at 10 Hz (its payload does not matter here)
        assembler.feed(can.Message(timestamp=0.1 * k, arbitration_id=frame_id, data=bytes(8), is_extended_id=False))
    assert assembler._stale_after(message) == pytest.approx(0.25, rel=0.01)  # 2.5 of its periods, not 0.1 s
