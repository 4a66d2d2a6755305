"""No traceback from any failure: the stage that failed is named, a crash report is written, and what was
computed before it is kept (online_id/util/stages.py, online_id/cli/crash.py)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from online_id.cli.crash import EXIT_INTERNAL_ERROR
from online_id.cli.main import main
from online_id.util import stages


@pytest.fixture(scope="module")
def short_run(tmp_path_factory):
    path = tmp_path_factory.mktemp("stages") / "run.csv"
    assert main(["simulate", "--out", str(path), "--duration", "21", "--rate", "100", "--seed", "3"]) == 0
    return path


def _one_line(err: str, prefix: str) -> str:
    lines = [line for line in err.splitlines() if line.startswith(prefix)]
    assert len(lines) == 1, err
    assert "Traceback" not in err
    return lines[0]


# -- the module ------------------------------------------------------------------------------------------

def test_the_innermost_stage_names_the_failure_and_absorb_records_it_only_in_a_session():
    with pytest.raises(ZeroDivisionError) as info:
        with stages.stage("outer"), stages.stage("inner"):
            1 / 0  # noqa: B018
    assert stages.stage_of(info.value) == "inner"

    @stages.stage("decorated")
    def fails():
        raise KeyError("x")

    with pytest.raises(KeyError) as info:
        fails()
    assert stages.stage_of(info.value) == "decorated"
    assert stages.absorb(ValueError("no session"), "polish") == "ValueError: no session"  # library use: no record
    with stages.session() as s:
        assert stages.absorb(ValueError("bad\nsecond line"), "polish") == "ValueError: bad"
    assert [(a.stage, a.error) for a in s.absorbed] == [("polish", "ValueError: bad")]
    with pytest.raises(KeyboardInterrupt):
        stages.absorb(KeyboardInterrupt(), "polish")  # an interrupt is not a failure to carry on from


def test_kept_results_are_flushed_newest_first_and_a_broken_writer_is_named():
    calls = []
    with stages.session() as s:
        stages.keep("a", lambda f: calls.append(("a", f.stage)))
        stages.keep("b", lambda f: 1 / 0)
        stages.keep("a", lambda f: calls.append(("a2", f.stage)))  # replaces the first "a"
        problems = s.flush(stages.Failure("polish", "ValueError: x"))
    assert calls == [("a2", "polish")]
    assert problems == ["could not write b: ZeroDivisionError: division by zero"]


# -- the command line ------------------------------------------------------------------------------------

def test_an_unexpected_failure_after_the_filter_is_one_line_a_crash_report_and_the_json_kept(
        short_run, tmp_path, capsys, monkeypatch):
    """Anything that is not an input error: exit 70, one line naming the stage and the crash report, the
    filter's estimate written with the failure marked; never a traceback."""
    from online_id.estimation import EstimationResult

    def broken_table(self):
        raise RuntimeError("table broke")

    monkeypatch.setattr(EstimationResult, "table", broken_table)
    out = tmp_path / "est.json"
    rc = main(["estimate", str(short_run), "--no-polish", "--quiet", "--json", str(out)])
    err = capsys.readouterr().err
    assert rc == EXIT_INTERNAL_ERROR == 70
    line = _one_line(err, "online-id: internal error in ")
    assert "internal error in estimate: RuntimeError: table broke; please report with " in line
    report = tmp_path / line.rsplit("please report with ", 1)[1]
    assert report.parent == tmp_path  # beside the outputs
    text = report.read_text()
    assert f"estimate {short_run} --no-polish --quiet --json {out}" in text
    for needle in ("numpy ", "scipy ", "filterpy ", "numba ", "online-id ", "Traceback (most recent call last)",
                   "RuntimeError: table broke", f"{short_run}: {short_run.stat().st_size:,} bytes"):
        assert needle in text, needle
    data = json.loads(out.read_text())
    assert data["failure"]["stage"] == "estimate" and "table broke" in data["failure"]["error"]
    assert data["failure"]["crash_report"] == str(report)
    assert data["samples"] == 2100 and all(np.isfinite(v["value"]) for v in data["parameters"].values())


def test_the_stage_that_failed_is_named_and_without_outputs_the_report_goes_to_the_temporary_folder(
        short_run, tmp_path, capsys, monkeypatch):
    import tempfile

    import online_id.estimation as estimation

    def broken(*args, **kwargs):
        raise IndexError("gone")

    monkeypatch.setattr(estimation, "judge_estimator", broken)  # called inside run_estimator: stage "filter"
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    rc = main(["estimate", str(short_run), "--no-polish", "--quiet"])
    line = _one_line(capsys.readouterr().err, "online-id: internal error in ")
    assert rc == EXIT_INTERNAL_ERROR
    assert line.startswith("online-id: internal error in filter: IndexError: gone; please report with ")
    assert (tmp_path / line.rsplit(" ", 1)[1]).is_file()


def test_an_input_error_after_the_filter_keeps_its_estimate(short_run, tmp_path, capsys, monkeypatch):
    from online_id.errors import OnlineIdError
    from online_id.estimation import EstimationResult

    def refuses(self):
        raise OnlineIdError("refused late")

    monkeypatch.setattr(EstimationResult, "events_summary", refuses)
    out = tmp_path / "est.json"
    rc = main(["estimate", str(short_run), "--no-polish", "--quiet", "--json", str(out)])
    assert rc == 2
    assert _one_line(capsys.readouterr().err, "online-id: error: ") == "online-id: error: refused late"
    assert json.loads(out.read_text())["failure"]["error"] == "refused late"


def test_a_failure_inside_the_polish_keeps_the_filter_estimate_and_names_it(short_run, tmp_path, capsys,
                                                                            monkeypatch):
    import online_id.batchfit.polish as polish_module

    def broken(*args, **kwargs):
        raise ZeroDivisionError("in the polish")

    monkeypatch.setattr(polish_module, "polish", broken)
    out = tmp_path / "est.json"
    rc = main(["estimate", str(short_run), "--polish", "--quiet", "--json", str(out)])
    err = capsys.readouterr().err
    assert rc == 0, err  # the filter's estimate stands
    line = _one_line(err, "online-id: warning: internal error in polish")
    assert "ZeroDivisionError: in the polish; the results above stand without it; please report with" in line
    data = json.loads(out.read_text())
    assert "the polish failed (ZeroDivisionError: in the polish): kept the filter's estimate" == data["polish"]["error"]
    assert "online" not in data  # the parameters are the filter's own
    assert (tmp_path / line.rsplit(" ", 1)[1]).is_file()


def test_a_failed_polish_of_the_fit_keeps_the_ga_best(short_run, tmp_path, capsys, monkeypatch):
    import online_id.batchfit.fit as fit_module

    def broken(*args, **kwargs):
        raise FloatingPointError("lsq broke")

    monkeypatch.setattr(fit_module, "guarded_least_squares", broken)
    out = tmp_path / "fit.json"
    rc = main(["fit", str(short_run), "--generations", "2", "--groups", "1", "--quiet", "--json", str(out)])
    err = capsys.readouterr().err
    assert rc == 0, err
    data = json.loads(out.read_text())
    assert data["choice"].startswith("the polish of the GA's minima failed (FloatingPointError: lsq broke)")
    assert [c["polished"] for c in data["candidates"]] == [False]
    assert "internal error in polish of the GA's minima: FloatingPointError: lsq broke" in err


def test_one_diagnosis_candidate_failing_keeps_the_others(short_run, monkeypatch):
    import online_id.diagnosis.diagnose as diagnose_module
    from online_id.io.tracklog import read_track_run
    from online_id.vehicle.loader import load_vehicle

    original = diagnose_module._fit_candidate

    def sometimes(name, *args):
        if name == "sensor_delay":
            raise ValueError("candidate broke")
        return original(name, *args)

    monkeypatch.setattr(diagnose_module, "_fit_candidate", sometimes)
    with stages.session() as s:
        d = diagnose_module.diagnose_gap(load_vehicle("haro2008"), read_track_run(short_run),
                                     effects=["sensor_delay", "accelerometer_gravity"])
    assert [c.name for c in d.candidates] == ["accelerometer_gravity"]
    assert d.to_json_dict()["failed_candidates"] == [
        {"name": "sensor_delay", "stage": "diagnosis candidate sensor_delay", "error": "ValueError: candidate broke"}]
    assert [a.stage for a in s.absorbed] == ["diagnosis candidate sensor_delay"]
