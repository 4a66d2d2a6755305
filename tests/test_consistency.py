"""The consistency verdict (online_id/trust/consistency.py): no false alarm on clean runs, a flag with a
reason on the issue's slips (offset, units, signs, a model that does not fit), honest labels, and
learning only inside the model's linear range.

The slips are judged through the Python entry points (run_estimator), as the CLI's input checks may
refuse some of them before the filter runs.
"""

from __future__ import annotations

import json
import warnings
from dataclasses import replace

import numpy as np
import pytest

from online_id.batchfit.cost import FitCost
from online_id.cli.main import main
from online_id.effects import parse_effect
from online_id.estimation import EstimateTrace, EstimationResult, make_estimator, run_estimator
from online_id.filters import FilterConfig
from online_id.filters.innovations import InnovationLog
from online_id.io.tracklog import write_track_run
from online_id.sim.simulator import simulate
from online_id.stream.samples import MEASURED_CHANNELS, samples_from_run
from online_id.trust import consistency as cons
from online_id.units import G
from online_id.vehicle import load_vehicle


@pytest.fixture(scope="module")
def car():
    return load_vehicle("haro2008")


def _run(car, *, seed=0, transform=None, **kw):
    run = simulate(car, car.truth("track"), seed=seed, **kw).run
    if transform is not None:
        transform(run)
    return run


def _estimate(car, run, filt="ekf", channels=None, config=None):
    est = make_estimator(car, filt, config=config)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # the resets of a broken run are counted, not shown
        return run_estimator(est, samples_from_run(run, channels))


# -- statistics ----------------------------------------------------------------------------------------
def test_ljung_box_tells_white_noise_from_a_correlated_sequence():
    rng = np.random.default_rng(0)
    white = rng.standard_normal(3000)
    ar = np.empty(3000)
    ar[0] = 0
    for k in range(1, 3000):
        ar[k] = 0.7 * ar[k - 1] + white[k]
    assert not cons.whiteness(white)[0]
    flagged, detail = cons.whiteness(ar)
    assert flagged and detail["sum_rho2"] > 0.5


def test_binomial_bound_allows_what_chance_gives():
    assert cons.binomial_upper(15, 1e-3, 0.00625) == 1  # P(2 or more of 15 at 1e-3) ≈ 1e-4
    assert cons.binomial_upper(1000, 0.01, 0.01) > 10


def test_window_size_test_passes_chi2_and_flags_inflated_innovations():
    rng = np.random.default_rng(1)
    t = np.arange(3000) * 0.02
    nis = rng.chisquare(1, 3000)
    assert cons.innovation_size(t, nis)[0] is None
    assert cons.innovation_size(t, 4 * nis)[0] == "large"
    assert cons.innovation_size(t, 0.01 * nis)[0] == "small"


def test_innovation_log_is_bounded_and_keeps_time_order():
    log = InnovationLog(capacity=5)
    for k in range(12):
        log.record(float(k), np.array([0, 3]), np.array([1.0, 2.0]), np.array([1.0, 1.0]), k > 6)
    rows = log.rows()
    assert len(log) == 5 and log.total == 12
    assert list(rows[:, 0]) == [7, 8, 9, 10, 11] and np.all(rows[:, 1] == 1)
    assert np.isnan(rows[0, 3]) and rows[0, 5] == 2.0


def test_the_innovation_log_keeps_its_last_capacity_rows_in_order():
    """The rows it hands on are those a ring buffer of its capacity holds, before and after it wraps."""
    log = InnovationLog(capacity=3000)
    N = len(MEASURED_CHANNELS)
    kept = []
    for k in range(7000):
        channels = np.array([k % 4]) if k % 3 else np.array([0, 1, 2, 3])
        nu, f = np.full(len(channels), 0.5 * k), np.full(len(channels), 1.0 + k)
        log.record(float(k), channels, nu, f, k % 2 == 0)
        row = np.full(2 + 2 * N, np.nan)  # time, converged, then ν and R/R_nominal of each of the N channels
        row[:2] = k, k % 2 == 0
        row[2 + channels], row[2 + N + channels] = nu, f
        kept = (kept + [row])[-3000:]
        if k in (0, 1023, 1024, 2999, 3000, 4500, 6999):
            assert len(log) == len(kept) and log.total == k + 1
            np.testing.assert_array_equal(log.rows(), np.array(kept))


def test_plausibility_passes_haros_cars_and_flags_the_race_car_result(car):
    for name in ("constructor", "track", "track60"):
        reasons, _ = cons.plausibility(car.truth(name).to_vector(), car.known)
        assert reasons == [], name
    # the race car: Mzz 62 kg·m² for a 982 kg car with l1 1.33, l2 1.07 m
    known = replace(car.known, M=982.0, ms=885.0, l1=1.33, l2=1.07)
    theta = replace(car.truth("track"), Mzz=62.0).to_vector()
    reasons, derived = cons.plausibility(theta, known)
    assert derived["dynamic_index"] == pytest.approx(62 / (982 * 1.33 * 1.07), rel=1e-3)
    assert any("dynamic index" in r for r in reasons)


def test_moved_and_at_limit_are_named():
    s = np.zeros(8)
    s[5] = np.log(4968 / 60000)  # the parameter that moved from 60,000 to 4,968
    s[0] = 4.9
    reasons, details = cons.parameter_reasons(s, np.full(8, 0.5), limit=5.0)
    assert details["at_limit"] == ["Mzz"]
    assert details["moved_prior_sigma"]["Kro"] == pytest.approx(abs(s[5]) / 0.5, abs=0.01)
    assert any("Kro" in r and "moved" in r for r in reasons)


# -- clean runs: no false alarm, accuracy kept -----------------------------------------------------------
@pytest.mark.parametrize("filt,seed", [("ekf", 3), ("ekf", 11), ("ukf", 5)])
def test_a_clean_run_is_consistent_and_accurate(car, filt, seed):
    res = _estimate(car, _run(car, seed=seed), filt)
    err = res.parameters.to_vector() / car.truth("track").to_vector() - 1
    assert np.abs(err).max() < {"ekf": 0.005, "ukf": 0.01}[filt], err
    c = res.consistency
    assert c["consistent"] and c["judged"], c["reasons"]
    assert c["innovations"]["segment"].startswith("after convergence")
    for ch in c["innovations"]["channels"].values():
        assert 0.7 < ch["rms_ratio"] < 1.3  # the innovations are the size the noise model says
    assert res.std_inflation == 1.0  # white innovations: the filter's σ as it is


def test_a_clean_run_without_roll_channels_is_consistent(car):
    res = _estimate(car, _run(car, seed=4), channels=("yaw_rate", "lateral_acceleration"))
    assert res.consistency["consistent"], res.consistency["reasons"]


# -- the slips: flagged with a reason -----------------------------------------------------------
SLIPS = {
    "a_y offset 0.3 m/s²": dict(effects=[parse_effect("sensor_bias=lateral_acceleration:0.3")]),
    "yaw-rate offset 0.02 rad/s": dict(effects=[parse_effect("sensor_bias=yaw_rate:0.02")]),
    "speed in km/h": dict(transform=lambda r: setattr(r, "speed", r.speed * 3.6)),
    "SAE yaw sign": dict(transform=lambda r: setattr(r, "yaw_rate", -r.yaw_rate)),
    "a_y in g": dict(transform=lambda r: setattr(r, "lateral_acceleration", r.lateral_acceleration / G)),
    "steering in degrees at 3°": dict(amplitude_rad=np.deg2rad(3.0), transform=lambda r: setattr(
        r, "steering_wheel_angle", np.rad2deg(r.steering_wheel_angle))),
}


@pytest.mark.parametrize("slip", list(SLIPS))
def test_a_slip_is_flagged_with_a_reason(car, slip):
    res = _estimate(car, _run(car, seed=7, **SLIPS[slip]))
    c = res.consistency
    assert not c["consistent"] and c["reasons"], slip
    # the evidence is the innovations or the filter's breakdowns, not only where the parameters ended
    assert any(r.startswith("innovations") or "resets" in r for r in c["reasons"]), c["reasons"]
    assert json.loads(json.dumps(res.to_json_dict()))["consistency"]["consistent"] is False
    # and it says what to try next (issue 30): an offset points to --offsets first, anything else to a lever
    steps = c["next_steps"]
    assert steps and all(s["because"] and ("add" in s or "run" in s) for s in steps), steps
    if "offset" in slip:
        assert steps[0]["lever"] == "offsets" and steps[0]["add"] == ["--offsets"], steps


def test_a_car_with_saturating_tyres_driven_hard_is_flagged(car):
    """Not Haro's structure: tyre forces saturate (effect tire_saturation), 60° chirp (about 1 g)."""
    run = _run(car, seed=2, amplitude_rad=np.deg2rad(60), effects=[parse_effect("tire_saturation=0.9")])
    res = _estimate(car, run, config=FilterConfig(linear_range_ay=np.inf))
    assert not res.consistency["consistent"], res.consistency


def test_innovations_that_are_not_white_widen_the_filters_sigma(car):
    """A model that misses the data leaves correlated innovations: fewer independent errors than corrections. The
    reported σ is the filter's × √τ (τ the integrated autocorrelation time of the flagged channel's innovations),
    said in the reason and the JSON; without the widening the linear EKF on this 0.9 g run is 3-10 of its σ off."""
    run = _run(car, seed=2, amplitude_rad=np.deg2rad(60), effects=[parse_effect("tire_saturation=0.9")])
    est = make_estimator(car, "ekf", config=FilterConfig(linear_range_ay=np.inf))
    res = run_estimator(est, samples_from_run(run))
    tau = res.std_inflation
    assert tau > 2, res.consistency["innovations"]
    assert any("σ widened" in r for r in res.consistency["reasons"]), res.consistency["reasons"]
    np.testing.assert_allclose(res.std, est.parameter_std * np.sqrt(tau))
    np.testing.assert_allclose(res.covariance, est.parameter_covariance * tau)
    assert res.to_json_dict()["std_inflation"] == tau


def test_correlation_time_of_white_and_of_correlated_series():
    rng = np.random.default_rng(1)
    white = rng.standard_normal(20_000)
    assert cons.correlation_time(white) == pytest.approx(1.0, abs=0.1)
    ar = np.empty_like(white)
    ar[0] = 0.0
    for k in range(1, len(white)):
        ar[k] = 0.8 * ar[k - 1] + white[k]
    assert cons.correlation_time(np.concatenate([ar, [np.nan]])) == pytest.approx(9.0, rel=0.25)  # (1+a)/(1-a)


# -- the linear range ------------------------------------------------------------------------------------
def test_samples_beyond_the_linear_range_are_counted_and_not_learned_from(car):
    run = _run(car, seed=1, duration_s=20.0)
    limit = 1.0  # m/s²: the 20 s chirp's a_y spends 73 % of its time beyond
    res = _estimate(car, run, config=FilterConfig(linear_range_ay=limit))
    beyond = int(np.count_nonzero(np.abs(run.lateral_acceleration[1:]) > limit))
    assert res.events["outside_linear_range"] == beyond
    assert "outside linear range" in res.events_summary()
    c = res.consistency
    assert c["outside_linear_range_fraction"] == pytest.approx(beyond / len(run), abs=1e-3)
    assert beyond / len(run) > 0.5
    assert not c["consistent"] and any("linear range" in r for r in c["reasons"])


def test_the_default_linear_range_keeps_every_sample_of_haros_protocol(car):
    run = _run(car, seed=0)
    assert np.all(np.abs(run.lateral_acceleration) < FilterConfig().linear_range_ay)


def test_the_fit_leaves_blocks_beyond_the_linear_range_out_of_its_cost(car):
    run = _run(car, seed=1, duration_s=20.0)
    everything = FitCost(car, run, car.prior.to_vector())
    linear = FitCost(car, run, car.prior.to_vector(), linear_range_ay=2.0, settle_s=0.5)
    assert everything.blocks_outside == 0
    assert 0 < linear.blocks_outside < everything.n_blocks_used
    assert linear.n_blocks_used == everything.n_blocks_used - linear.blocks_outside
    assert len(linear.residuals(np.zeros(8))) == linear.n_blocks_used * len(linear.channels)


def test_fit_residual_verdict(car):
    rng = np.random.default_rng(3)
    white = rng.standard_normal((3000, 2))
    ok = cons.judge_fit(white, ("yaw_rate", "lateral_acceleration"), car.truth("track").to_vector(), car.known, [])
    assert ok["consistent"], ok["reasons"]
    drift = white + np.sin(np.arange(3000) / 30.0)[:, None] * 2
    bad = cons.judge_fit(drift, ("yaw_rate", "lateral_acceleration"), car.truth("track").to_vector(), car.known,
                         ["b1"], outside_fraction=0.8)
    text = "; ".join(bad["reasons"])
    assert not bad["consistent"] and "residuals not white" in text and "b1" in text and "linear range" in text
    offset = cons.judge_fit(white + [0.5, 0.0], ("yaw_rate", "lateral_acceleration"),
                            car.truth("track").to_vector(), car.known, [])
    (reason,) = offset["reasons"]
    assert reason.startswith("residual means far from zero (yaw_rate +0.5") and "lateral_acceleration" not in reason


# -- honest labels --------------------------------------------------------------------------------------
def test_a_parameter_that_moved_is_never_said_to_stay_near_its_prior(car):
    prior = car.prior
    moved = replace(prior, Kro=4968.0)
    res = EstimationResult(
        filter="ekf", samples=1, wall_s=0.0, parameters=moved, std=np.full(8, 1.0),
        relative_std=np.full(8, 0.9), prior=prior, prior_relative_std=np.full(8, 1.0),
        events={}, gated={},
        trace=EstimateTrace(np.zeros(1), np.zeros((1, 8)), np.zeros((1, 8))))
    table = res.table()
    assert "stays near prior" not in table
    kro = next(line for line in table.splitlines() if line.startswith("Kro"))
    assert kro.split()[-2:] == ["no", f"{np.log(150000 / 4968):.1f}"]
    data = res.to_json_dict()
    assert data["moved_prior_sigma"]["Kro"] == pytest.approx(np.log(150000 / 4968))
    assert "Kro" in data["not_informed"] and data["informed"]["Kro"] is False


# -- the command line -----------------------------------------------------------------------------------
def test_estimate_prints_the_verdict_and_strict_exits_3(car, tmp_path, capsys):
    log = tmp_path / "offset.csv"
    write_track_run(_run(car, seed=5, duration_s=30.0,
                         effects=[parse_effect("sensor_bias=lateral_acceleration:0.3")]), log)
    out_json = tmp_path / "r.json"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        assert main(["estimate", str(log), "--quiet", "--json", str(out_json)]) == 0
        out = capsys.readouterr().out
        assert "verdict: INCONSISTENT — innovations" in out
        # the next step, after the verdict line: the command as typed with --offsets
        assert f"try: online-id estimate {log} --quiet --json {out_json} --offsets" in out.split("verdict:")[1]
        assert main(["estimate", str(log), "--quiet", "--strict", "--json", str(out_json)]) == 3
    data = json.loads(out_json.read_text())  # written before the exit status
    assert data["consistency"]["consistent"] is False and data["consistency"]["reasons"]


def test_listen_shows_the_verdict_live(car):
    import io

    from online_id.cli.listen_cmd import _LiveTable

    run = _run(car, seed=1, duration_s=3.0)
    est = make_estimator(car, "ekf")
    samples = list(samples_from_run(run))
    est.update_many(samples)
    stream = io.StringIO()
    _LiveTable(1.0, stream=stream)(est, samples[-1])
    assert "verdict: not judged yet" in stream.getvalue()  # 3 s: too few corrections to judge


# -- a run nobody judged ----------------------------------------------------------------------------------
def test_a_run_too_short_to_judge_is_neither_consistent_nor_inconsistent(car):
    """3 s: too few block innovations to test. ``consistent`` must be None (JSON null) with the reason, never
    True: a script reading it must not trust a run nobody judged."""
    res = _estimate(car, _run(car, seed=1, duration_s=3.0))
    c = res.consistency
    assert c["consistent"] is None and c["judged"] is False and not c["reasons"], c
    assert "fewer than" in c["not_judged_because"] and str(cons.MIN_INNOVATIONS) in c["not_judged_because"]
    assert json.loads(json.dumps(res.to_json_dict()))["consistency"]["consistent"] is None
    line = cons.verdict_line(c)
    assert line.startswith("verdict: not judged") and c["not_judged_because"] in line


def test_a_filter_that_made_no_correction_says_so():
    c = cons._verdict([], False, cons.innovations_not_judged(np.zeros((0, 10))), {})
    assert c["consistent"] is None and "no correction" in c["not_judged_because"]


def test_a_failed_check_is_inconsistent_even_when_the_innovations_could_not_be_judged():
    c = cons._verdict(["implausible dynamic index 9"], False, "too short", {})
    assert c["consistent"] is False
    line = cons.verdict_line(c)
    assert line.startswith("verdict: INCONSISTENT — implausible") and "too short" in line


def test_a_fit_with_too_few_residuals_is_not_judged(car):
    few = np.random.default_rng(0).standard_normal((40, 2))
    c = cons.judge_fit(few, ("yaw_rate", "lateral_acceleration"), car.truth("track").to_vector(), car.known, [])
    assert c["consistent"] is None and "fewer than" in c["not_judged_because"], c


def test_strict_neither_passes_nor_fails_an_unjudged_run_silently(car, tmp_path, capsys):
    log = tmp_path / "short.csv"
    write_track_run(_run(car, seed=2, duration_s=3.0), log)
    out_json = tmp_path / "r.json"
    assert main(["estimate", str(log), "--quiet", "--no-polish", "--strict", "--json", str(out_json)]) == 0
    captured = capsys.readouterr()
    assert "verdict: not judged yet — " in captured.out
    assert "--strict: the run could not be judged" in captured.err
    data = json.loads(out_json.read_text())
    assert data["consistency"]["consistent"] is None and data["consistency"]["not_judged_because"]


def test_the_batch_summary_says_not_judged():
    from online_id.batch import summary_row

    doc = {"log": "a.csv", "status": "ok", "estimate": {"consistency": {
        "consistent": None, "reasons": [], "judged": False, "not_judged_because": "too short"}}}
    row = summary_row(doc, "a.json")
    assert row["consistent"] == "not judged" and row["consistency_reasons"] == "too short"
    doc["estimate"]["consistency"].update(consistent=False, reasons=["x"], judged=True)
    assert summary_row(doc, "a.json")["consistent"] == "no"


# -- what to try next ------------------------------------------------------------------------------------
def test_next_steps_name_the_likely_lever_first():
    steps = cons.next_steps({"biased": ["lateral_acceleration"]})
    assert [s["lever"] for s in steps] == ["offsets"] and steps[0]["add"] == ["--offsets"]
    # a bias on innovations that are also far too large and correlated: the structure first (the race car)
    steps = cons.next_steps({"biased": ["yaw_rate"], "large": ["yaw_rate"], "not_white": ["yaw_rate"]})
    assert [s["lever"] for s in steps] == ["structure", "offsets"]
    assert steps[0]["run"] == ["online-id", "diagnose", "LOG", "--json", "DIAG.json"]
    # ... unless a_y − V·r shows the offset without any model
    steps = cons.next_steps({"kinematic": ["lateral_acceleration", "yaw_rate"], "large": ["yaw_rate"],
                             "biased": ["yaw_rate"]})
    assert steps[0]["lever"] == "offsets"
    # offsets already estimated and still biased: the structure; a roll channel: its own sensor_bias effect
    steps = cons.next_steps({"biased": ["lateral_acceleration", "roll_rate"]}, offsets_on={"lateral_acceleration"})
    assert [s["lever"] for s in steps] == ["sensor_bias", "structure"]
    assert steps[0]["add"] == ["--effect", "sensor_bias:roll_rate"]
    # the fit has no --offsets: a sensor_bias effect per channel
    assert cons.next_steps({"biased": ["yaw_rate"]}, tool="fit")[0]["add"] == ["--effect", "sensor_bias:yaw_rate"]
    assert cons.next_steps({"linear_range": []})[0]["add"] == ["--effect", "tire_saturation"]
    assert cons.next_steps({"small": ["roll_angle"]})[0]["run"] == ["online-id", "check", "LOG"]
    assert cons.next_steps({"resets": []}, not_informed=["Mxx"])[-1]["lever"] == "excitation"
    assert cons.next_steps({}, not_informed=["Mxx"]) == []  # a consistent run: nothing to try


def test_next_step_lines_extend_the_command_as_typed():
    verdict = {"consistent": False, "reasons": ["x"], "judged": True,
               "next_steps": cons.next_steps({"biased": ["yaw_rate"], "large": ["roll_angle"]})}
    lines = cons.verdict_lines(verdict, ["estimate", "my run.csv", "--quiet"], "my run.csv")
    assert lines[0].startswith("verdict: INCONSISTENT")
    assert lines[1].endswith("try: online-id estimate 'my run.csv' --quiet --offsets")
    assert lines[2].endswith("try: online-id diagnose 'my run.csv' --json DIAG.json")
    # a CAN log: diagnose reads it through the same DBC and map, for the same car
    can = ["estimate", "r.log", "--dbc", "car.dbc", "--signals=car", "--vehicle", "rav4_2017", "--quiet"]
    assert cons.verdict_lines(verdict, can, "r.log")[2].endswith(
        "try: online-id diagnose r.log --dbc car.dbc --signals=car --vehicle rav4_2017 --json DIAG.json")
    built_in = cons.next_step_lines(verdict)  # no log: the built-in run; no argv: the flags to add
    assert built_in[0].endswith("add --offsets to the command") and built_in[1].endswith("diagnose --json DIAG.json")


def test_a_fit_verdict_says_what_to_try_next(car):
    white = np.random.default_rng(3).standard_normal((3000, 2))
    offset = cons.judge_fit(white + [0.5, 0.0], ("yaw_rate", "lateral_acceleration"),
                            car.truth("track").to_vector(), car.known, [], not_determined=["Mxx"])
    assert [s["lever"] for s in offset["next_steps"]] == ["sensor_bias", "excitation"]
    ok = cons.judge_fit(white, ("yaw_rate", "lateral_acceleration"), car.truth("track").to_vector(), car.known, [])
    assert ok["next_steps"] == []
