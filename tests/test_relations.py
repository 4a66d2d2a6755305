"""A channel that does not belong is named (online_id/trust/relations.py): a_y that does not follow V·r, a yaw rate
that does not follow the steering, a dead or swapped channel, roll that does not follow a_y; a time column in
milliseconds. Refused with the right cause (exit 2), never "not enough excitation"; clean runs, the race car,
the RAV4 log and the independent simulator pass."""

from __future__ import annotations

import json
import re
from dataclasses import replace

import numpy as np
import pytest

from online_id.cli.main import main
from online_id.errors import OnlineIdError
from online_id.io.tracklog import read_track_run, write_track_run
from online_id.trust.plausibility import ImplausibleInputError, judge_run, parse_allow
from online_id.trust.relations import AGREE_CORRELATION, BROKEN_CORRELATION, measure
from online_id.vehicle.loader import load_vehicle
from tests.conftest import SHARED

HARO = load_vehicle("haro2008")
REVS_CSV = SHARED / "realdata" / "revs_250lm" / "revs_250lm_laps_0-400s.csv"


@pytest.fixture(scope="module")
def issue_run(tmp_path_factory):
    """The run of issue 29's table: ``online-id simulate --duration 20`` (1 kHz, the chirp at 80 km/h)."""
    path = tmp_path_factory.mktemp("relations") / "run.csv"
    assert main(["simulate", "--out", str(path), "--duration", "20"]) == 0
    return read_track_run(path)


def _noise_like(values, seed=1):
    return np.random.default_rng(seed).normal(np.mean(values), np.std(values), len(values))


def _corrupted(run, how: str):
    n = len(run)
    return {
        "a_y noise": lambda: replace(run, lateral_acceleration=_noise_like(run.lateral_acceleration)),
        "a_y reversed": lambda: replace(run, lateral_acceleration=run.lateral_acceleration[::-1].copy()),
        "yaw rate dead": lambda: replace(run, yaw_rate=np.zeros(n)),
        "yaw rate swapped with roll rate": lambda: replace(run, yaw_rate=run.roll_rate, roll_rate=run.yaw_rate),
        "yaw rate of noise": lambda: replace(run, yaw_rate=_noise_like(run.yaw_rate)),
        "steering dead": lambda: replace(run, steering_wheel_angle=np.zeros(n)),
        "roll of noise": lambda: replace(run, roll_angle=_noise_like(run.roll_angle)),
    }[how]()


@pytest.mark.parametrize("how", ["a_y noise", "a_y reversed"])
def test_the_issue_rows_are_refused_naming_the_channel_and_kept_when_allowed(how, issue_run, tmp_path, capsys):
    """Issue 29's table: exit 2 naming lateral_acceleration (not "not enough excitation"); with the check
    allowed, the filter's JSON is written, flagged, and a failing polish is named in it."""
    log = write_track_run(_corrupted(issue_run, how), tmp_path / "bad.csv")
    out = tmp_path / "est.json"
    assert main(["estimate", str(log), "--quiet", "--json", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "Traceback" not in err and not out.exists()
    assert "lateral_acceleration does not follow speed × yaw_rate" in err
    assert "while yaw_rate and steering_wheel_angle agree (correlation +1.00) over 18" in err
    assert "wrong column, or a broken sensor? (if the car really is like that: --allow-implausible ay_follows)" in err
    assert "not enough excitation" not in err

    rc = main(["estimate", str(log), "--quiet", "--json", str(out), "--allow-implausible", "ay_follows"])
    err = capsys.readouterr().err
    assert rc == 0 and "Traceback" not in err and "internal error" not in err
    data = json.loads(out.read_text())
    assert data["plausibility"]["allowed"] == ["ay_follows"]  # flagged
    assert data["consistency"]["consistent"] is False
    assert all(np.isfinite(p["value"]) for p in data["parameters"].values())
    if "error" in data["polish"]:  # the polish refused: the filter's estimate stays, and why
        assert data["polish"]["error"].endswith("kept the filter's estimate") and "online" not in data
    if how == "a_y reversed":  # no parameter set fits a reversed a_y: the polish says so within a few evaluations
        error = data["polish"]["error"]  # (it "converged" with a_y 1.2x its own spread from the data, σ about 1 %)
        assert "the model misses lateral_acceleration and no longer gets closer" in error
        assert "of the channel's own spread" in error
        assert int(re.search(r"stopped after (\d+) evaluations", error).group(1)) <= 15  # it ran 37 to "converge"


@pytest.mark.parametrize("how, channel, check, words", [
    ("yaw rate dead", "yaw_rate", "yaw_follows", "yaw_rate is constant (0 rad/s) over the whole run"),
    ("yaw rate swapped with roll rate", "yaw_rate", "yaw_follows", "yaw_rate does not follow the steering"),
    ("yaw rate of noise", "yaw_rate", "yaw_follows", "yaw_rate does not follow the steering"),
    ("steering dead", "steering_wheel_angle", "steering_follows", "steering_wheel_angle is constant (0 rad)"),
    ("roll of noise", "roll_angle", "roll_follows", "roll_angle does not follow lateral_acceleration"),
])
def test_a_channel_that_does_not_belong_is_named_with_its_evidence(how, channel, check, words, issue_run):
    """Issue 30's last row: a dead or swapped yaw-rate channel said "not enough excitation"."""
    report = judge_run(_corrupted(issue_run, how), HARO)
    assert [(r.check, r.channel) for r in report.failures] == [(check, channel)]
    assert words in report.failures[0].message
    with pytest.raises(ImplausibleInputError, match=f"--allow-implausible {check}"):
        report.enforce()
    assert report.enforce(parse_allow(check))  # allowed: a warning
    assert not any("not enough excitation" in n for n in report.enforce(parse_allow(check)))
    moot = [r for r in report.results if r.status == "skipped" and r.channel == channel]
    assert moot or channel == "roll_angle"  # the unit checks on that channel do not blame a unit


def test_clean_runs_and_the_real_logs_pass_with_their_margins(issue_run):
    """The relations on runs that belong: every one agrees, well above the threshold that names a channel."""
    revs = read_track_run(REVS_CSV)
    for run, vehicle in ((issue_run, HARO), (revs, load_vehicle("revs_250lm")), (revs, HARO)):
        report = judge_run(run, vehicle)
        assert not report.failures, [r.message for r in report.failures]
        follows = [r for r in report.results if r.check.endswith("_follows")]
        assert follows and all(r.status == "ok" for r in follows)
        m = measure(run.time, run.steering_wheel_angle, run.speed, run.yaw_rate, run.lateral_acceleration,
                    run.roll_angle, vehicle.known, vehicle.prior)
        for key in ("ay_vr", "yaw_steer", "ay_steer"):
            assert m[key].correlation > AGREE_CORRELATION + 0.05 > BROKEN_CORRELATION + 0.25, (run.source, key)


def test_a_real_log_with_a_broken_channel_is_refused_too():
    revs = read_track_run(REVS_CSV)
    vehicle = load_vehicle("revs_250lm")
    for bad, check in ((replace(revs, lateral_acceleration=revs.lateral_acceleration[::-1].copy()), "ay_follows"),
                       (replace(revs, yaw_rate=np.full(len(revs), 0.01)), "yaw_follows")):
        assert [r.check for r in judge_run(bad, vehicle).failures] == [check]


def test_the_rav4_log_turns_too_little_to_be_judged_and_is_not_refused(rav4_paths):
    from online_id.drivers.sources import load_run

    log, dbc = rav4_paths
    run = load_run(log, dbc=dbc, signals="toyota_rav4_2017").run
    report = judge_run(run, load_vehicle("rav4_2017"))
    assert not report.failures
    assert {r.status for r in report.results if r.check.endswith("_follows")} == {"not judged"}
    assert any("not enough turning to check that each channel follows" in n for n in report.enforce())
    # a dead yaw-rate channel is unambiguous even there: a_y and the steering agree (0.89) as the car turns
    dead = judge_run(replace(run, yaw_rate=np.zeros(len(run))), load_vehicle("rav4_2017")).failures
    assert [(r.check, r.channel) for r in dead] == [("yaw_follows", "yaw_rate")]
    assert dead[0].message.startswith("yaw_rate is constant (0 rad/s) over the whole run, while lateral_acceleration"
                                      " and steering_wheel_angle agree (correlation +0.89)")


def test_the_independent_simulator_passes():
    pytest.importorskip("vehiclemodels")
    from tests.independent_sim import simulate_mb, vehicle_for

    run = simulate_mb(2, "sines", duration_s=20.0, rate_hz=100.0, seed=2)
    report = judge_run(run, vehicle_for(2))
    assert not report.failures and report.by_check("ay_follows").status == "ok"


@pytest.mark.parametrize("scale, rate, unit, hz", [(1e3, 100, "milliseconds", "100 Hz"),
                                                   (1e3, 1000, "milliseconds", "1000 Hz"),
                                                   (1e6, 100, "microseconds", "100 Hz")])
def test_a_time_column_in_another_unit_is_named(scale, rate, unit, hz, issue_run, tmp_path, capsys):
    """Issue 30: a time column 1000x too large gave "no known slip" from the a_y check."""
    step = int(round(1000 / rate))
    run = replace(issue_run, **{c: getattr(issue_run, c)[::step] for c in issue_run.channels})
    log = write_track_run(replace(run, time=run.time * scale), tmp_path / "ms.csv")
    for command in (["estimate", str(log), "--quiet"], ["check", str(log)], ["fit", str(log), "--quiet"]):
        assert main(command) == 2
        err = capsys.readouterr().err.strip()
        assert f"column 'time': time steps of {scale / rate:.6g} (median) — {unit}? ({hz} if so);" \
               " online-id needs seconds" in err and err.count("\n") == 0
    from online_id.drivers.sources import run_from_dataframe

    pd = pytest.importorskip("pandas")
    with pytest.raises(OnlineIdError, match=f"{unit}"):
        run_from_dataframe(pd.DataFrame({c: getattr(run, c) for c in run.channels}).assign(time=run.time * scale))
