"""``online-id batch`` on a local Dask cluster of 2 workers: a row per log, failures are rows, re-runs skip.

The cluster is real (``dask.distributed.LocalCluster``, worker processes talking over loopback TCP).
"""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

import online_id
from online_id.batch import SUMMARY_COLUMNS, BatchOptions, log_key, process_log, run_batch
from online_id.cli.main import main
from online_id.io.tracklog import read_track_run, write_track_run
from online_id.sim.simulator import simulate
from online_id.vehicle.loader import load_vehicle
from online_id.vehicle.parameters import PARAMETER_NAMES


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    """Three short simulated runs (different seeds and speeds), a truncated copy and a missing file."""
    d = tmp_path_factory.mktemp("batch_logs")
    vehicle = load_vehicle("haro2008")
    paths = []
    for seed, kmh in ((1, 80), (2, 70), (3, 90)):
        sim = simulate(vehicle, vehicle.truth("track"), duration_s=6.0, rate_hz=500.0, speed_mps=kmh / 3.6,
                       seed=seed, truth_name="track")
        p = d / f"run{seed}.csv"
        write_track_run(sim.run, p)
        paths.append(p)
    text = paths[0].read_text()
    truncated = d / "truncated.csv"
    truncated.write_text(text[: len(text) // 2].rsplit(",", 1)[0])  # cut inside a row
    return paths, truncated, d / "missing.csv"


def _read_summary(path):
    with open(path, newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    return rows


def test_batch_on_two_workers_a_row_per_log_and_failures_are_rows(logs, tmp_path, capsys):
    good, truncated, missing = logs
    out = tmp_path / "out"
    argv = ["batch", *map(str, good), str(truncated), str(missing), "--out", str(out), "--workers", "2"]
    assert main(argv) == 1  # some logs failed: exit 1, after every log was tried
    rows = _read_summary(out / "summary.csv")
    assert tuple(rows[0].keys()) == SUMMARY_COLUMNS
    assert [r["log"] for r in rows] == [*map(str, good), str(truncated), str(missing)]
    assert [r["status"] for r in rows] == ["ok", "ok", "ok", "failed", "failed"]
    assert "truncated.csv" in rows[3]["error"] and "line" in rows[3]["error"]
    assert "missing.csv" in rows[4]["error"]
    for r, p in zip(rows[:3], good):
        # the batch gives exactly what estimating the log alone gives (the API, as `online-id estimate`)
        run = read_track_run(p)
        direct = online_id.estimate(p)
        assert int(r["samples"]) == direct.result.samples == len(run)
        got = np.array([float(r[n]) for n in PARAMETER_NAMES])
        np.testing.assert_allclose(got, [direct.parameters[n].value for n in PARAMETER_NAMES], rtol=1e-7)
        doc = json.loads((out / f"{log_key(p)}.json").read_text())
        assert doc["status"] == "ok" and doc["estimate"]["samples"] == len(run)
        # yes, no, or not judged (a run too short to test: consistent null, issue 30), as the JSON says
        verdict = doc["estimate"]["consistency"]["consistent"]
        assert r["consistent"] == {True: "yes", False: "no", None: "not judged"}[verdict], (r, verdict)
    err = capsys.readouterr()
    assert "[5/5]" in err.err and "2 worker" in err.err
    assert "3 ok, 2 failed" in err.out


def test_batch_rerun_skips_logs_already_done_and_retries_failed(logs, tmp_path):
    good, truncated, _ = logs
    out = tmp_path / "out"
    first = run_batch([*good[:2], truncated], out, BatchOptions(), workers=2)
    assert [r["status"] for r in first.rows] == ["ok", "ok", "failed"]
    mtimes = {p: (out / f"{log_key(p)}.json").stat().st_mtime_ns for p in good[:2]}
    second = run_batch([*good, truncated], out, BatchOptions(), workers=2)
    assert [r["reused"] for r in second.rows] == ["yes", "yes", "no", "no"]
    assert [r["status"] for r in second.rows] == ["ok", "ok", "ok", "failed"]
    for p in good[:2]:
        assert (out / f"{log_key(p)}.json").stat().st_mtime_ns == mtimes[p]  # not rewritten
    # other options are other work: the UKF runs the logs again
    third = run_batch(good[:1], out, BatchOptions(filter="ukf"), workers=0)
    assert third.rows[0]["reused"] == "no" and third.rows[0]["filter"] == "ukf"


def test_process_log_never_raises_and_names_the_error(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("time,speed\n0,1\n")
    row = process_log(str(bad), str(tmp_path), BatchOptions())
    assert row["status"] == "failed" and "steering_wheel_angle" in row["error"]
    doc = json.loads((tmp_path / f"{log_key(bad)}.json").read_text())
    assert doc["status"] == "failed" and doc["error"] == row["error"]


def test_two_logs_with_one_name_do_not_collide(tmp_path):
    a, b = tmp_path / "a" / "run.csv", tmp_path / "b" / "run.csv"
    assert log_key(a) != log_key(b)


def test_a_straight_line_in_a_season_is_not_green_and_the_page_says_why(tmp_path):
    """Issue 39: a straight line informs nothing, yet read "verdict: consistent" and was the fleet page's only
    green row. Now its verdict is "nothing learned" (summary.csv: not judged, with why, and which parameters it
    did not inform), its row on the page is amber and the page says why under the table; a run that informed
    its parameters keeps them listed, and the season's handling metrics are there with σ."""
    import re

    vehicle = load_vehicle("haro2008")
    chirp, straight = tmp_path / "chirp.csv", tmp_path / "straight.csv"
    write_track_run(simulate(vehicle, vehicle.truth("track"), duration_s=20.0, rate_hz=100.0, seed=1).run, chirp)
    line = simulate(vehicle, vehicle.truth("track"), duration_s=60.0, rate_hz=100.0, maneuver="sine",
                    amplitude_rad=0.0, seed=2).run
    line.meta = {}  # a logged run: no truth sidecar
    write_track_run(line, straight)
    result = run_batch([chirp, straight], tmp_path / "out", BatchOptions(estimate={"polish": False}), workers=0)
    rows = {r["log"]: r for r in _read_summary(result.summary_path)}
    s, c = rows[str(straight)], rows[str(chirp)]
    assert s["consistent"] != "yes" and "informed none" in s["consistency_reasons"]
    assert s["informed"] == "" and s["not_informed"].split() == list(PARAMETER_NAMES)
    assert set(c["informed"].split()) == set(PARAMETER_NAMES) and c["not_informed"] == ""
    assert float(c["understeer_gradient_deg_per_g"]) > 0 and float(c["understeer_gradient_deg_per_g_std"]) > 0
    assert c["characteristic_speed_kind"] == "characteristic"
    doc = json.loads(next((tmp_path / "out").glob("straight.csv.*.json")).read_text())
    assert doc["estimate"]["consistency"]["nothing_learned"] is True
    assert any("no --vehicle" in w for w in doc["source_warnings"])  # a logged run, no car named: said
    page = (tmp_path / "out" / "index.html").read_text()
    table = page[page.index('<table class="fleet">'):page.index("</table>", page.index('<table class="fleet">'))]
    row = next(r for r in re.findall(r"<tr[^>]*>.*?</tr>", table, re.S) if "straight.csv" in r)
    assert 'class="warn"' in row and 'class="ok"' not in row and "NOTHING LEARNED" in row
    why = page[page.index("Why a log is not green"):]
    why = why[:why.index("</ul>")]
    assert "straight.csv" in why and "informed none" in why
    assert '<table class="handling-fleet">' in page
