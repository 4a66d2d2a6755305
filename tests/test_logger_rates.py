"""Issue 36's acceptance: right at the rates real loggers use (25, 50, 100, 200 Hz), as at 1 kHz.

Every run here is built as a logger sees a car: the car integrated at 10 kHz (the simulator's default,
``online_id.sim.simulator.INTEGRATION_RATE_HZ``; the steering a cubic between the fine samples) and every k-th
fine sample logged, the sensor noise added at the logged rate; never integrated at the logger's rate with the
filters' own hold, which hides the hold's half-sample lag. The independent simulator (CommonRoad's multibody
car, its own RK4) is integrated at 1 kHz and decimated to 100 Hz.

Measured on the shared 2-core machine (2026-11-27, the built-in chirp, 60 s at 80 km/h, the Table 6 car): the
worst parameter 0.5 % (25 Hz), 0.6 % (50), 0.7 % (100), 1.0 % (200) with the EKF over 3 seeds, the UKF 0.6-0.9 %;
with the hold the same runs gave b1 −28 % at 100 Hz and −72 % at 25 Hz (the issue's table).
"""

from __future__ import annotations

import functools
import json
import warnings

import numpy as np
import pytest

from online_id.cli.main import main
from online_id.effects import parse_effect, parse_effect_to_estimate
from online_id.estimation import make_estimator, run_estimator
from online_id.filters.config import FilterConfig
from online_id.io.tracklog import OPTIONAL_COLUMNS, REQUIRED_COLUMNS, TrackRun
from online_id.sim.simulator import simulate
from online_id.stream.samples import samples_from_run
from online_id.vehicle import load_vehicle
from online_id.vehicle.parameters import PARAMETER_NAMES

CAR = load_vehicle("haro2008")
TRUTH = CAR.truth("track")
THETA = TRUTH.to_vector()
RATES = (25.0, 50.0, 100.0, 200.0)
#: Every parameter within 1 % of the truth, 2 % at 25 Hz (the issue's bound).
TOLERANCE = {25.0: 0.02, 50.0: 0.01, 100.0: 0.01, 200.0: 0.01}
#: ...and within this many σ of it: a bias with a tight σ is what the hold gave (b1 at 25 Hz: z −6.6).
Z_BOUND = 3.0
#: False alarms on the true model: at most one run in twenty at each rate.
FALSE_ALARM_SEEDS, FALSE_ALARMS_ALLOWED = 20, 1


@functools.cache
def logged(rate_hz: float, seed: int):
    """The built-in chirp integrated at 10 kHz and logged at ``rate_hz`` (once per session per seed)."""
    return simulate(CAR, TRUTH, rate_hz=rate_hz, seed=seed, truth_name="track").run


def _estimate(run, filter_name="ekf", **config):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # (the default prior's note)
        est = make_estimator(CAR, filter_name, config=FilterConfig(**config) if config else None)
        return est, run_estimator(est, samples_from_run(run))


def _report(res) -> str:
    err = res.parameters.to_vector() / THETA - 1
    z = (res.parameters.to_vector() - THETA) / res.std
    return ", ".join(f"{n} {100 * e:+.2f}% ({s:+.1f}σ)" for n, e, s in zip(PARAMETER_NAMES, err, z))


@pytest.mark.parametrize("filter_name", ["ekf", "ukf"])
@pytest.mark.parametrize("rate", RATES)
def test_a_run_sampled_at_a_loggers_rate_gives_the_8_and_a_consistent_verdict(rate, filter_name):
    run = logged(rate, 0)
    assert run.meta["integration_rate_hz"] == 10_000.0 and run.meta["rate_hz"] == rate
    _, res = _estimate(run, filter_name)
    err = res.parameters.to_vector() / THETA - 1
    z = (res.parameters.to_vector() - THETA) / res.std
    assert np.abs(err).max() < TOLERANCE[rate], _report(res)
    assert np.abs(z).max() < Z_BOUND, _report(res)
    assert res.consistency["judged"] and res.consistency["consistent"], res.consistency["reasons"]


@pytest.mark.parametrize("rate", [25.0, 100.0])
def test_the_hold_fails_where_the_cubic_holds(rate):
    """The same logged run through the filter's old zero-order hold: b1 far off and the true model judged
    INCONSISTENT (what the tests above would catch if the cubic were lost)."""
    _, res = _estimate(logged(rate, 0), intersample="hold")
    b1 = res.parameters.to_vector()[PARAMETER_NAMES.index("b1")] / THETA[PARAMETER_NAMES.index("b1")] - 1
    assert b1 < -0.15, _report(res)
    assert res.consistency["consistent"] is False


@pytest.mark.parametrize("rate", RATES)
def test_the_verdict_holds_its_false_alarm_rate_at_a_loggers_rate(rate):
    """Twenty seeds of the true model at each rate (EKF): at most one judged INCONSISTENT (5 %), every one
    judged. About 30 s a rate on the shared machine."""
    flagged = []
    for seed in range(FALSE_ALARM_SEEDS):
        _, res = _estimate(logged(rate, 100 + seed))
        assert res.consistency["judged"], (seed, res.consistency)
        if res.consistency["consistent"] is False:
            flagged.append((seed, res.consistency["reasons"]))
    assert len(flagged) <= FALSE_ALARMS_ALLOWED, flagged


#: Seeds of the 100 Hz chirp whose estimate with accelerometer_gravity estimated converged only at 54-59 s of 60
#: before the tempered filter's plateau counted (FilterHealth.plateaued), the rest of the run judged tempered.
PLATEAU_SEEDS = (114, 118)


@pytest.mark.parametrize("filter_name", ["ekf", "ukf"])
@pytest.mark.parametrize("seed", PLATEAU_SEEDS)
def test_an_estimated_effect_at_100_hz_converges_in_time_and_is_judged_consistent(seed, filter_name):
    """An extra state (accelerometer_gravity, on a run without it: k true 0) dilutes what the run tells of the 8;
    at 100 Hz the tempered filter's σ then sat on a plateau just above converged_log_std (b1 0.036-0.039 for
    12 s) and the verdict judged a tempered, sluggish filter: INCONSISTENT in 6 of 14 seeds with the EKF, 7 of
    13 with the UKF (innovations 1.1-1.3×, not white). Once its σ stop falling the filter counts as converged."""
    run = logged(100.0, seed)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        est = make_estimator(CAR, filter_name, effects=[parse_effect_to_estimate("accelerometer_gravity")])
        res = run_estimator(est, samples_from_run(run))
    assert est.converged_at is not None and est.converged_at < 45.0, est.converged_at
    err = res.parameters.to_vector() / THETA - 1
    z = (res.parameters.to_vector() - THETA) / res.std
    assert np.abs(err).max() < TOLERANCE[100.0] and np.abs(z).max() < Z_BOUND, _report(res)
    k = est.extra_states["effects"]["accelerometer_gravity"]["k"]
    assert abs(k["value"]) < Z_BOUND * k["std"], k
    assert res.consistency["judged"] and res.consistency["consistent"], res.consistency["reasons"]


def test_a_plateau_counts_only_settled_below_its_bound_and_no_longer_falling():
    """FilterHealth.plateaued on made-up σ: falling 20 % a window is not a plateau, flat is (after a whole
    window), a parameter that moves restarts the window, and σ above PLATEAU_LOG_STD never counts."""
    from online_id.filters.health import PLATEAU_LOG_STD, PLATEAU_WINDOW_S

    def health():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return make_estimator(CAR, "ekf").health

    s, step = np.zeros(8), 0.05
    times = np.arange(0.0, 4 * PLATEAU_WINDOW_S, step)
    flat = health()
    seen = [flat.plateaued(t, s, np.full(8, 0.05)) for t in times]
    assert not any(seen[:int(PLATEAU_WINDOW_S / step)]) and seen[-1]
    falling = health()
    assert not any(falling.plateaued(t, s, np.full(8, 0.09 * 0.8 ** (t / PLATEAU_WINDOW_S))) for t in times)
    moving = health()
    assert not any(moving.plateaued(t, s + (0.2 if int(t / 1.0) % 2 else 0.0), np.full(8, 0.05)) for t in times)
    wide = health()
    assert not any(wide.plateaued(t, s, np.full(8, PLATEAU_LOG_STD)) for t in times)


@functools.cache
def _saturating_run():
    """μ 0.7 on both axles, the chirp at 80° of steering-wheel amplitude and 80 km/h (0.84 g: about all μ 0.7
    gives this car; the 1 kHz envelope test's case, tests/test_tyre_filter.py), integrated at 10 kHz (the force
    law's fixed point per fine step) and logged at 100 Hz. (At 90°, 0.85 g, the tyres spend so long saturated
    that D1 and b1 are poorly seen at any rate: at 1 kHz D1 −7.5 % (3σ), b1 −32 %.)"""
    return simulate(CAR, TRUTH, speed_mps=80 / 3.6, amplitude_rad=np.deg2rad(80), rate_hz=100.0,
                    effects=[parse_effect("tire_saturation=0.7")], seed=7).run


@pytest.mark.parametrize("filter_name", ["ekf", "ukf"])
def test_saturating_tyres_sampled_at_100_hz_give_the_8_and_mu(filter_name):
    """The issue's: μ 0.7 at 0.84 g sampled at 100 Hz, the 8 within 2 % and μ within 2 %, each within 3σ of
    the truth, EKF and UKF (the hold gave μ 0.598 ± 0.009, z −11, and b1 −40 %)."""
    run = _saturating_run()
    assert np.abs(run.lateral_acceleration).max() > 0.83 * 9.81
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        est = make_estimator(CAR, filter_name, effects=[parse_effect_to_estimate("tire_saturation")])
        res = run_estimator(est, samples_from_run(run))
    err = res.parameters.to_vector() / THETA - 1
    z = (res.parameters.to_vector() - THETA) / res.std
    assert np.abs(err).max() < 0.02 and np.abs(z).max() < Z_BOUND, _report(res)
    mu = est.extra_states["effects"]["tire_saturation"]["mu"]
    assert abs(mu["value"] / 0.7 - 1) < 0.02 and abs(mu["value"] - 0.7) < Z_BOUND * mu["std"], mu
    assert res.consistency["consistent"], res.consistency["reasons"]


def test_simulate_at_100_hz_then_estimate_is_consistent(tmp_path):
    """The command line as a user runs it: ``simulate --rate 100`` (integrated at 10 kHz by default), then
    ``estimate``: the issue's run gave INCONSISTENT (yaw 1.86×, a_y 1.81×)."""
    log, out = tmp_path / "run.csv", tmp_path / "est.json"
    assert main(["simulate", "--rate", "100", "--out", str(log), "--seed", "3"]) == 0
    assert main(["estimate", str(log), "--quiet", "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    assert data["consistency"]["consistent"] is True, data["consistency"]
    assert data["intersample"] == "cubic"
    truth = TRUTH.to_dict()
    for name in PARAMETER_NAMES:  # the filter's and the polished estimate
        assert data["online"]["parameters"][name]["value"] == pytest.approx(truth[name], rel=0.01), name
        assert data["parameters"][name]["value"] == pytest.approx(truth[name], rel=0.01), name


def test_an_independent_car_sampled_at_100_hz_is_judged_as_at_1_khz():
    """CommonRoad's car 1 (Pacejka tyres, combined slip, load transfer, its own RK4) at 0.9 g, integrated at
    1 kHz and decimated to 100 Hz, with ``--effect tire_saturation``. That car is not Haro's model at any rate
    (measured 2026-11-27: innovations 64-131× their size at 1 kHz, 19-36× at 100 Hz; EKF and UKF apart by tens
    of σ on Mxx, D2, b1 at both rates), so the 8 cannot be judged exact here; what must hold at 100 Hz is what
    held at 1 kHz: both filters flag the run INCONSISTENT with the innovations as their reason, and the tyre
    limit, which the run does inform, comes out the same (μ 1.155 / 1.144 at 1 kHz, 1.099 / 1.152 at 100 Hz,
    EKF / UKF). About 60 s."""
    pytest.importorskip("vehiclemodels", reason="the test extra commonroad-vehicle-models is not installed")
    from tests.independent_sim import simulate_mb, vehicle_for

    fine = simulate_mb(1, "chirp", speed_kmh=80, duration_s=20.0, rate_hz=1000.0, amplitude_deg=60, seed=1)
    assert np.max(np.abs(fine.lateral_acceleration)) > 0.85 * 9.81
    kw = {c: (None if getattr(fine, c) is None else getattr(fine, c)[::10])
          for c in (*REQUIRED_COLUMNS, *OPTIONAL_COLUMNS)}
    coarse = TrackRun(**kw, source="CommonRoad car 1 decimated to 100 Hz", meta=dict(fine.meta))
    assert np.allclose(np.diff(coarse.time), 0.01)
    vehicle = vehicle_for(1)
    mu = {}
    for name, run in (("1 kHz", fine), ("100 Hz", coarse)):
        for f in ("ekf", "ukf"):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                est = make_estimator(vehicle, f, effects=[parse_effect_to_estimate("tire_saturation")])
                res = run_estimator(est, samples_from_run(run))
            verdict = res.consistency
            assert verdict["judged"] and verdict["consistent"] is False, (name, f, verdict)
            assert any(r.startswith("innovations") for r in verdict["reasons"]), (name, f, verdict["reasons"])
            mu[name, f] = est.extra_states["effects"]["tire_saturation"]["mu"]["value"]
    for f in ("ekf", "ukf"):
        assert abs(mu["100 Hz", f] / mu["1 kHz", f] - 1) < 0.06, mu


def test_a_log_far_from_the_model_is_retempered_not_broken_down():
    """The race car's first 60 s (100 Hz, its a_y biased, past the model): the rate-scaled tempering let b1 run to
    1 % of its prior in 3 s and the filter broke down at 13.8 s (5 resets; every parameter held at the prior).
    Now the burst starts it again from the prior tempered 10x more: retempered once, not diverged, the
    parameters learned (moved off the prior) and finite, and the verdict still INCONSISTENT."""
    from online_id.io.tracklog import read_track_run
    from tests.conftest import SHARED

    log = SHARED / "realdata" / "revs_250lm" / "revs_250lm_laps_0-400s.csv"
    if not log.exists():
        pytest.fail(f"the real-data log is missing: {log} (shared/ must sit beside the checkout)")
    run = read_track_run(log).slice(0, 6000)
    car = load_vehicle("revs_250lm")
    with pytest.warns(RuntimeWarning, match="start again from the prior, tempered"):
        est = make_estimator(car, "ekf")
        res = run_estimator(est, samples_from_run(run))
    assert res.events.get("retempered") == 1 and "diverged" not in res.events, res.events
    moved = np.abs(np.log(res.parameters.to_vector() / car.prior.to_vector()))
    assert np.isfinite(moved).all() and moved.max() > 0.1
    assert res.consistency["consistent"] is False
    # a clean run never retempers (the acceptance runs above would have said so in their events)
    _, clean = _estimate(logged(100.0, 0))
    assert "retempered" not in clean.events
