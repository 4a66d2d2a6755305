"""Control of the prior: widening of the vehicle's σ is reported, --keep-prior-std honours it, and
--fix holds a parameter exactly in the online filters and the batch fit."""

from __future__ import annotations

import json
import warnings
from importlib import resources

import numpy as np
import pytest

from online_id.batchfit.fit import FitConfig, fit_run
from online_id.batchfit.ga import GAConfig
from online_id.cli.main import main
from online_id.errors import OnlineIdError
from online_id.estimation import make_estimator, run_estimator
from online_id.filters import FilterConfig
from online_id.sim.simulator import simulate
from online_id.stream.samples import samples_from_run
from online_id.vehicle import PARAMETER_NAMES, load_vehicle
from online_id.vehicle.loader import parse_vehicle

#: What the filters must reach on the built-in 60 s run with one parameter held at its truth (the
#: free ones reach 0.5 % in tests/test_filters.py; fixing one must not cost accuracy).
FIXED_TRUE_TOLERANCE = 0.005
#: A wrong fixed Mzz (half the truth) must move the others by more than this somewhere.
WRONG_FIX_SHIFT = 0.01


@pytest.fixture(scope="module")
def car():
    return load_vehicle("haro2008")


@pytest.fixture(scope="module")
def run80(car):
    return simulate(car, car.truth("track"), speed_mps=80 / 3.6, seed=1).run


def _narrow_car(rel_std: float):
    text = (resources.files("online_id.vehicle") / "data" / "haro2008.toml").read_text(encoding="utf-8")
    start = text.index("[prior_relative_std]")
    end = text.index("[", start + 1)
    table = "[prior_relative_std]\n" + "".join(f"{n} = {rel_std}\n" for n in PARAMETER_NAMES) + "\n"
    return parse_vehicle(text[:start] + table + text[end:], source="narrow.toml")


def test_a_narrow_prior_is_widened_and_says_so(car):
    narrow = _narrow_car(0.01)
    est = make_estimator(narrow)
    np.testing.assert_allclose(est.prior_log_std, FilterConfig().prior_log_std_floor)
    spread = est.prior_spread
    assert set(spread.widened) == set(PARAMETER_NAMES)
    assert spread.widened["Mzz"] == (0.01, 1.0)
    data = spread.to_json_dict()
    assert data["parameters"]["Kro"] == {"given": 0.01, "used": 1.0} and "Kro is 4σ away" in data["reason"]
    assert any("widened" in note and "Mzz 1 %" in note for note in spread.notes())


def test_keep_prior_std_honours_the_file(car):
    est = make_estimator(_narrow_car(0.01), config=FilterConfig(prior_log_std_floor=0.0))
    np.testing.assert_allclose(est.prior_log_std, 0.01)
    assert est.prior_spread.to_json_dict() is None and est.prior_spread.notes() == []


def test_a_fits_sigma_is_taken_as_given_and_only_its_gaps_are_widened(car):
    given = np.full(8, 0.02)
    given[3] = np.nan  # a parameter the fit could not determine
    est = make_estimator(car, prior_relative_std=given)
    assert est.prior_log_std[0] == pytest.approx(0.02)
    assert list(est.prior_spread.widened) == ["D2"]


@pytest.mark.parametrize("filt", ["ekf", "ukf"])
def test_fixed_at_the_truth_the_others_are_still_recovered(car, run80, filt):
    truth = car.truth("track")
    if filt == "ukf":  # the UKF is slower: its contract (exact, no reset) on a shorter stretch
        run80 = run80.slice(0, 20000)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a fixed parameter's zero variance must not trip the health check
        est = make_estimator(car, filt, fixed={"Mzz": truth.Mzz})
        res = run_estimator(est, samples_from_run(run80))
    assert res.parameters.Mzz == truth.Mzz  # exactly
    assert res.std[0] == 0.0 and np.all(res.trace.values[:, 0] == truth.Mzz)
    assert res.events.get("resets", 0) == 0
    assert res.fixed == {"Mzz": truth.Mzz} and res.to_json_dict()["fixed"] == {"Mzz": truth.Mzz}
    assert "Mzz" not in res.to_json_dict()["not_informed"]
    assert "FIXED" in res.table().splitlines()[2]
    if filt == "ekf":
        err = res.parameters.to_vector()[1:] / truth.to_vector()[1:] - 1
        assert np.all(np.abs(err) < FIXED_TRUE_TOLERANCE), dict(zip(PARAMETER_NAMES[1:], err))
        assert all(ok for n, ok in res.informed.items() if n != "Mzz")


def test_fixed_at_a_wrong_value_the_result_differs(car, run80):
    truth = car.truth("track")
    right = run_estimator(make_estimator(car, fixed={"Mzz": truth.Mzz}), samples_from_run(run80))
    wrong = run_estimator(make_estimator(car, fixed={"Mzz": 0.5 * truth.Mzz}), samples_from_run(run80))
    assert wrong.parameters.Mzz == 0.5 * truth.Mzz
    shift = np.abs(wrong.parameters.to_vector()[1:] / right.parameters.to_vector()[1:] - 1)
    assert shift.max() > WRONG_FIX_SHIFT, shift


def test_fit_with_a_fixed_parameter(car):
    truth = car.truth("track")
    run = simulate(car, truth, duration_s=20.0, rate_hz=500.0, seed=3).run
    config = FitConfig(ga=GAConfig(generations=300))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        right = fit_run(car, run, config, fixed={"Mzz": truth.Mzz})
        wrong = fit_run(car, run, config, fixed={"Mzz": 0.5 * truth.Mzz})
    assert right.parameters.Mzz == truth.Mzz and wrong.parameters.Mzz == 0.5 * truth.Mzz
    assert right.std[0] == 0.0 and "Mzz" not in right.undetermined
    err = right.parameters.to_vector()[1:] / truth.to_vector()[1:] - 1
    assert np.all(np.abs(err) < FIXED_TRUE_TOLERANCE), err
    assert right.cost < wrong.cost
    data = right.to_json_dict()
    assert data["fixed"] == {"Mzz": truth.Mzz}
    assert all(c["parameters"]["Mzz"] == truth.Mzz for c in data["candidates"])
    assert "FIXED" in right.table().splitlines()[2]


def test_cli_fix_and_its_errors(tmp_path, capsys):
    log = tmp_path / "run.csv"
    assert main(["simulate", "--out", str(log), "--duration", "10", "--rate", "200", "--seed", "3"]) == 0
    out = tmp_path / "est.json"
    assert main(["estimate", str(log), "--quiet", "--fix", "Mzz=700", "--fix", "b2", "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    assert data["fixed"] == {"Mzz": 700.0, "b2": 0.5}  # b2 at the haro2008 prior
    assert data["parameters"]["Mzz"] == {"value": 700.0, "std": 0.0}
    # polished by default like any run (it was switched off by --fix): the held parameters stay held in it
    assert "error" not in data["polish"] and data["online"]["parameters"]["Mzz"] == {"value": 700.0, "std": 0.0}
    assert data["polish"]["parameters"]["b2"] == {"value": 0.5, "std": 0.0}
    assert data["parameters"]["D1"] != data["online"]["parameters"]["D1"]
    assert data["prior_widened"]["parameters"]["Kro"] == {"given": 0.15, "used": 1.0}
    err = capsys.readouterr().err
    assert "held fixed" in err and "prior σ widened" in err
    assert main(["estimate", str(log), "--quiet", "--keep-prior-std", "--json", str(out)]) == 0
    assert json.loads(out.read_text())["prior_widened"] is None
    for bad, needle in [("Izz=3", "unknown parameter 'Izz'"), ("Mzz=-1", "positive"), ("Mzz=abc", "not a number")]:
        assert main(["estimate", str(log), "--quiet", "--fix", bad]) == 2
        assert needle in capsys.readouterr().err


def test_every_parameter_fixed_is_refused(car):
    with pytest.raises(OnlineIdError, match="nothing left"):
        make_estimator(car, fixed=car.prior.to_dict())


def test_convergence_plot_counts_time_from_the_start_draws_the_prior_and_marks_what_was_not_informed(car):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from online_id.plots.convergence import draw_convergence

    sim = simulate(car, car.truth("track"), duration_s=4.0, rate_hz=200.0, maneuver="sine",
                   amplitude_rad=np.deg2rad(5), frequency_hz=0.2, seed=1)
    run = sim.run
    run.time = run.time + 46410.0  # a logger's bus clock
    res = run_estimator(make_estimator(car, fixed={"b2": 0.5}), samples_from_run(run, ("yaw_rate",
                                                                                   "lateral_acceleration")))
    # 4 s of slow steering and no roll channel cannot inform roll
    assert not res.informed["Kro"] and any(res.informed.values())
    fig = draw_convergence([("EKF", res)])
    try:
        axes = fig.axes
        lo, hi = axes[0].get_xlim()
        assert lo < 1.0 and hi < 10.0, (lo, hi)  # seconds from the start, not 46,410
        kro = axes[PARAMETER_NAMES.index("Kro")]
        assert any(line.get_label() == "prior" for line in kro.get_lines()) or any(
            "off scale: prior" in t.get_text() for t in kro.texts)
        assert any(t.get_text() == "not informed" for t in kro.texts)
        assert any(t.get_text() == "fixed" for t in axes[PARAMETER_NAMES.index("b2")].texts)
        for n, ax in zip(PARAMETER_NAMES, axes):
            expected = "fixed" if n == "b2" else "" if res.informed[n] else "not informed"
            marks = [t.get_text() for t in ax.texts if t.get_text() in ("fixed", "not informed")]
            assert marks == ([expected] if expected else []), (n, marks)
    finally:
        plt.close(fig)


def test_the_tyre_filters_hold_the_roll_parameters_without_a_roll_channel(car):
    """No roll channel: Mxx, Aro, Kro cannot be told apart by the data, and a free unobserved Kro drove the tyre model
    into stiff sub-stepping on the race car. With saturating tyres they are held at the prior and a note says why;
    a roll parameter the user fixed keeps the user's value; with a roll channel, or linear tyres, nothing changes."""
    from online_id.effects import parse_effect_to_estimate
    from online_id.filters.prior import ROLL_PARAMETERS

    tyre = [parse_effect_to_estimate("tire_saturation")]
    no_roll = ("yaw_rate", "lateral_acceleration")
    est = make_estimator(car, "ekf", effects=tyre, channels=no_roll, fixed={"Kro": 90000.0})
    assert est.fixed == {"Mxx": car.prior.Mxx, "Aro": car.prior.Aro, "Kro": 90000.0}
    assert np.all(est.log_scale_std[[PARAMETER_NAMES.index(n) for n in ROLL_PARAMETERS]] == 0)
    notes = est.prior_spread.notes()
    assert any(n.startswith("no roll channel: Mxx, Aro held at the prior") for n in notes), notes
    assert make_estimator(car, "ekf", effects=tyre, channels=no_roll + ("roll_rate",)).fixed == {}
    assert make_estimator(car, "ekf", channels=no_roll).fixed == {}
    assert make_estimator(car, "ukf", effects=tyre).fixed == {}  # channels not said: nothing assumed
