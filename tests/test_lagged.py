"""The lagged-output form of a delay (online_id/filters/lagged.py): reading a late channel ahead of the
steering, its error against the exact delay, and a filter that holds samples back yet works each once."""

from __future__ import annotations

import math

import numpy as np
import pytest

from online_id.effects import parse_effect, parse_effect_to_estimate
from online_id.estimation import make_estimator, run_estimator
from online_id.filters.lagged import MAX_LAG_S, Retimer
from online_id.sim.simulator import SensorNoise, simulate
from online_id.stream.samples import Sample, samples_from_run
from online_id.vehicle import load_vehicle

CAR = load_vehicle("haro2008")


def _retimer(t, y, speed=None, max_gap_s=0.1):
    r = Retimer(max_gap_s)
    for k, tk in enumerate(t):
        r._times.append(float(tk))
        r._samples.append(Sample(float(tk), 0.0, 20.0 if speed is None else float(speed[k]), yaw_rate=float(y[k])))
    return r


@pytest.mark.parametrize("rate_hz, bound", [(100.0, 3e-4), (250.0, 2e-5), (1000.0, 3e-7)])
def test_reading_between_samples_is_within_its_stated_error(rate_hz, bound):
    """The docstring's figures: a 4 Hz sine (the top of Haro's chirp) read at any fraction of a period,
    within (2πfh)³/60 of its amplitude; a linear reading would be off by (2πfh)²/8 (8e-3 at 100 Hz)."""
    t = np.arange(0.0, 3.0, 1.0 / rate_hz)
    r = _retimer(t, np.sin(2 * np.pi * 4.0 * t))
    tq = np.linspace(0.5, 2.5, 4001)
    err = np.abs([r.read("yaw_rate", x) for x in tq] - np.sin(2 * np.pi * 4.0 * tq)).max()
    assert err < bound
    assert err < (2 * np.pi * 4.0 / rate_hz) ** 3 / 60 * 1.1


def test_samples_come_out_once_in_order_with_the_late_channel_read_ahead():
    rate = 200.0
    t = np.arange(0.0, 2.0, 1.0 / rate)
    y = np.sin(2 * np.pi * 1.5 * t)
    V = 20.0 + t
    r = Retimer(0.1)
    r.set_lags([0.0123, 0.0, 0.0, 0.0], 0.02)
    out = []
    for k in range(len(t)):
        out += r.push(Sample(t[k], 0.1, V[k], yaw_rate=y[k], roll_angle=float(k)))
        # a sample waits until two samples beyond its lagged reading have arrived
        assert all(s.time + 0.02 < t[k] for s in out)
    out += r.drain()
    assert [s.time for s in out] == list(t)
    assert [s.roll_angle for s in out] == [float(k) for k in range(len(t))]  # a channel without a lag is as it came
    read = np.array([np.nan if s.yaw_rate is None else s.yaw_rate for s in out])
    inside = t + 0.0123 <= t[-1]
    assert np.allclose(read[inside], np.sin(2 * np.pi * 1.5 * (t[inside] + 0.0123)), atol=1e-4)
    assert np.isnan(read[~inside]).all()  # beyond the end of the stream: absent, not invented
    assert np.allclose([s.speed for s in out][:-5], (V + 0.02)[:-5], atol=1e-9)  # the speed read ahead too


def test_no_reading_across_a_gap_or_a_missing_value():
    t = np.concatenate([np.arange(0.0, 1.0, 0.01), np.arange(1.5, 2.0, 0.01)])
    y = np.cos(t)
    y[120] = np.nan
    r = _retimer(t, y)
    assert r.read("yaw_rate", 1.2) is None  # inside the 0.5 s gap
    assert r.read("yaw_rate", t[120] + 0.004) is None and r.read("yaw_rate", t[119] + 0.004) is None
    assert r.read("yaw_rate", 0.505) == pytest.approx(math.cos(0.505), abs=1e-6)
    assert r.read("yaw_rate", -0.1) is None and r.read("yaw_rate", 2.5) is None


def test_the_filter_holds_samples_back_and_works_every_one_of_them():
    """With a delay state the estimator holds samples until the late channel arrives; ``finish`` (which
    run_estimator calls) works the rest: every sample counted once, the clock unbroken, and a sample going
    back in time counted as invalid, not queued."""
    sim = simulate(CAR, CAR.truth("track"), duration_s=2.0, rate_hz=200.0, noise=SensorNoise.none())
    est = make_estimator(CAR, "ekf", effects=[parse_effect_to_estimate("sensor_delay:yaw_rate:0.02")])
    samples = list(samples_from_run(sim.run))
    for s in samples[:100]:
        est.update(s)
    held = 100 - est.events["samples"]
    assert 0 < held <= MAX_LAG_S * 200 + 3
    est.update(samples[50])  # back in time
    assert est.events["invalid_samples"] == 1
    for s in samples[100:]:
        est.update(s)
    est.finish()
    assert est.events["samples"] == len(samples) + 1
    assert est.events.get("gaps", 0) == 0 and est.events.get("missing_samples", 0) == 0
    assert est._last_time == samples[-1].time


def test_a_run_with_a_delay_and_no_delay_state_is_unchanged_by_the_form():
    """Without a lag among the extra states nothing is held back (the reading is not in the path)."""
    est = make_estimator(CAR, "ekf", offsets=True)
    assert est._retimer is None
    est = make_estimator(CAR, "ekf", effects=[parse_effect("steering_delay=0.05")])
    assert est._retimer is not None
    res = run_estimator(est, samples_from_run(simulate(CAR, CAR.truth("track"), duration_s=1.0, rate_hz=100.0).run))
    assert res.samples == res.events["samples"] == 100


def test_a_delay_estimated_beyond_what_a_delay_can_be_is_a_reason_in_the_verdict():
    """On the race car a gyro delay forced on the filter (with the tyres) went to −0.19 ± 0.006 s: model error,
    not a delay. Any extra state with physical bounds more than 3σ beyond them says so in the verdict."""
    from online_id.filters.base import N_AUG
    from online_id.trust.consistency import judge_estimator

    sim = simulate(CAR, CAR.truth("track"), duration_s=2.0, rate_hz=200.0)
    est = make_estimator(CAR, "ekf", effects=[parse_effect_to_estimate("sensor_delay:yaw_rate")])
    res = run_estimator(est, samples_from_run(sim.run))
    assert not any("takes up model error" in r for r in res.consistency["reasons"])
    x, P = est.x.copy(), est.P.copy()
    x[N_AUG] = -0.19
    P[N_AUG, N_AUG] = 0.006 ** 2
    est._set(x, P)
    reasons = judge_estimator(est)["reasons"]
    assert any(r.startswith("sensor_delay(yaw_rate) delay_s -0.19 s is not what it stands for (0 to 0.25 s)")
               for r in reasons), reasons
