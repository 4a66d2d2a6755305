"""The pieces of the pages of issue 27 without a browser (tests/test_browser.py opens them in one): the
excitation meters and the innovation windows (online_id/trust/over_time.py), thinning, the report workflow's
parts and commands, and the live page's server beside an estimation loop."""

from __future__ import annotations

import json
import shlex
import socket
import threading
import urllib.request
from dataclasses import replace

import numpy as np
import pytest

from online_id.report.page import MAX_POINTS, envelope
from online_id.sim.simulator import simulate
from online_id.stream.samples import MEASURED_CHANNELS
from online_id.trust.check import check_run
from online_id.trust.over_time import innovation_windows, learned_by_window, window_length
from online_id.vehicle import PARAMETER_NAMES, load_vehicle


@pytest.fixture(scope="module")
def car():
    return load_vehicle("haro2008")


@pytest.fixture(scope="module")
def short_run(car):
    return simulate(car, car.truth("track"), duration_s=12.0, rate_hz=100.0, seed=2).run


def test_the_fisher_meter_ends_on_checks_bound_and_sums_to_the_whole_run(car, short_run):
    rep = check_run(short_run, car)
    m = rep.excitation
    assert m.share.shape == (len(m.start), len(PARAMETER_NAMES))
    np.testing.assert_allclose(m.share.sum(axis=0), 1.0, rtol=1e-12)
    # had the run ended after its last window, the bound is check's own
    np.testing.assert_allclose(m.bound[-1], rep.decisive.crlb_relative_std, rtol=1e-6)
    assert np.all(np.diff(m.bound, axis=0) <= 1e-12 + 1e-9 * m.bound[:-1])  # information only adds


def test_the_fisher_meter_puts_the_information_where_the_steering_is(car, short_run):
    """Steering only in the second half: the first half's windows hold (next to) none of the information."""
    half = short_run.time >= short_run.time[0] + 6.0
    quiet = replace(short_run, steering_wheel_angle=np.where(half, short_run.steering_wheel_angle, 0.0))
    m = check_run(quiet, car).excitation
    early = m.start + m.window_s <= short_run.time[0] + 6.0
    assert early.any() and (~early).any()
    assert m.share[early].sum(axis=0).max() < 1e-3, m.share[early].sum(axis=0)


def test_the_filters_meter_counts_what_it_gained_not_what_it_forgot():
    t = np.arange(0, 10, 0.01)
    values = np.full((len(t), 8), 2.0)
    std = np.full((len(t), 8), 1.0)
    std[t >= 3.0] = 0.1  # learned at 3 s: σ_rel from 50 % to 5 %
    std[t >= 7.0] = 1.0  # reopened at 7 s: a fall, not a lesson
    m = learned_by_window(t, values, std, window_s=1.0)
    np.testing.assert_allclose(m.share.sum(axis=0), 1.0)
    assert np.argmax(m.share[:, 0]) == 3 and m.share[3, 0] == pytest.approx(1.0)


def test_innovation_windows_measure_against_the_nominal_noise():
    rng = np.random.default_rng(0)
    n = 5000
    N = len(MEASURED_CHANNELS)  # rows: time, converged, ν of each channel, R/R_nominal of each channel
    yaw, ay = MEASURED_CHANNELS.index("yaw_rate"), MEASURED_CHANNELS.index("lateral_acceleration")
    rows = np.full((n, 2 + 2 * N), np.nan)
    rows[:, 0] = np.arange(n) / 50.0  # 50 corrections per second
    rows[:, 1] = 1.0
    rows[:, 2 + yaw] = 2.0 * rng.standard_normal(n)  # yaw rate: twice its expected spread
    rows[:, 2 + N + yaw] = 1.0
    rows[:, 2 + ay] = rng.standard_normal(n)  # lateral acceleration: 1σ of S, but the filter inflated R ×4 to get there
    rows[:, 2 + N + ay] = 4.0
    wins = {w.channel: w for w in innovation_windows(rows)}
    assert set(wins) == {"yaw_rate", "lateral_acceleration"}
    for w in wins.values():
        assert np.nanmedian(w.rms) == pytest.approx(2.0, rel=0.1), w.channel
        assert np.all(w.bound[np.isfinite(w.bound)] > 1.0)


def test_a_window_length_keeps_the_meter_readable():
    for duration in (5.0, 60.0, 400.0, 3600.0, 36000.0):
        assert duration / window_length(duration) <= 200


def test_thinning_keeps_every_peak():
    rng = np.random.default_rng(1)
    t = np.arange(100_000) * 1e-3
    y = rng.standard_normal(len(t))
    y[54_321] = 40.0
    y[77_777] = -35.0
    tt, yy = envelope(t, y)
    assert len(tt) <= MAX_POINTS and np.all(np.diff(tt) > 0)
    assert yy.max() == 40.0 and yy.min() == -35.0


def test_the_report_keeps_the_other_parts_when_one_fails(car, short_run):
    from online_id.report.run_page import render
    from online_id.workflows import report

    rep = report(short_run, vehicle=car, fit=False, effects="no_such_effect")
    assert rep.estimate is not None and rep.check is not None and rep.fit is None and rep.diagnosis is None
    assert "no_such_effect" in rep.errors["diagnose"]
    assert rep.skipped == ["fit"] and rep.commands == {}  # data in memory: no command line reproduces it
    page = render(rep)
    assert "diagnose failed" in page and "no_such_effect" in page and "Not made (--no-fit)" in page
    doc = json.loads(rep.to_json())
    assert doc["estimate"]["parameters"].keys() == set(PARAMETER_NAMES)
    assert "fit" not in doc and doc["errors"]["diagnose"]


def test_every_command_a_report_lists_is_one_the_cli_takes():
    from online_id.cli.main import build_parser
    from online_id.workflows.report_job import commands

    lines = commands("laps.csv", vehicle="revs_250lm", filter="ukf", fit=False, generations=7, effects=["sensor_bias"],
                     dbc="car.dbc", signals="car_signals", resample=80.0, allow_implausible="yaw_sign",
                     out="laps.html")
    assert set(lines) == {"check", "estimate", "fit", "diagnose", "report"}
    parser = build_parser()
    for part, line in lines.items():
        words = shlex.split(line)
        assert words[:2] == ["online-id", part]
        args = parser.parse_args(words[1:])
        assert str(args.log) == "laps.csv" and args.vehicle == "revs_250lm" and str(args.dbc) == "car.dbc"
    assert "--no-fit" in lines["report"] and "--filter ukf" in lines["estimate"]
    assert "--generations 7" in lines["fit"] and "--effects sensor_bias" in lines["diagnose"]
    assert all("--resample 80" in lines[p] for p in ("check", "estimate", "fit", "diagnose"))  # the estimate too
    assert "--drop-nan" in commands("laps.csv", drop_nan=True)["estimate"]


def test_report_resamples_the_estimate_with_the_rest_and_counts_time_from_the_start(car, tmp_path):
    """Issue 39: ``report --resample 80`` put check, fit and diagnose on the grid but not the estimate (the RAV4
    log: 4,974 samples against 4,799), and a CAN log's bus clock made the time axes read 46.41k s. A jittered
    run on a logger's clock: the estimate has check's samples, its handling is on the page, the axes start at 0."""
    import re

    from online_id.io.tracklog import write_track_run
    from online_id.report.run_page import render
    from online_id.workflows import report

    run = simulate(car, car.truth("track"), duration_s=8.0, rate_hz=100.0, seed=3).run
    rng = np.random.default_rng(1)
    run.time = run.time + 46410.0 + rng.uniform(-2e-3, 2e-3, len(run.time))  # a bus clock, jittered
    log = write_track_run(run, tmp_path / "bus.csv")
    rep = report(log, vehicle=car, fit=False, diagnose=False, resample=80.0)
    assert rep.estimate.result.samples == rep.check.result.samples == len(rep.run)
    assert "--resample 80" in rep.commands["estimate"]
    page = render(rep)
    spec = re.search(r'data-for="run-channels">(.*?)</script>', page).group(1)
    xs = json.loads(spec.replace("<\\/", "</"))["data"][0]["x"]
    assert xs[0] == pytest.approx(0.0, abs=0.02) and max(xs) < 10.0
    assert "log clock 46,410" in page
    assert 'id="handling-bode"' in page and 'data-metric="understeer_gradient"' in page


def test_the_live_page_serves_beside_the_loop_and_a_stalled_client_holds_nothing(car, short_run):
    """A client that sends half a request and never reads, and one that hangs up, beside an estimation loop
    calling the view after every sample: the loop finishes, and the page's snapshot has its last numbers."""
    from online_id.estimation import make_estimator
    from online_id.report.live import LiveView
    from online_id.stream.samples import samples_from_run

    view = LiveView("test", "127.0.0.1", 0)
    url = view.start()
    host, port = url.removeprefix("http://").rstrip("/").split(":")
    try:
        stalled = socket.create_connection((host, int(port)))
        stalled.sendall(b"GET /snapshot.json HTTP/1.1\r\nHost: x\r\n")  # never finished, never read
        gone = socket.create_connection((host, int(port)))
        gone.sendall(b"GET /plotly.min.js HTTP/1.1\r\nHost: x\r\n\r\n")
        gone.close()  # hung up before the 4.8 MB answer
        est = make_estimator(car, "ekf")
        samples = list(samples_from_run(short_run))

        def loop():
            for s in samples:
                est.update(s)
                view(est, s, None)

        worker = threading.Thread(target=loop)
        worker.start()
        worker.join(timeout=120)
        assert not worker.is_alive(), "the estimation loop waited on the page's clients"
        with urllib.request.urlopen(url + "snapshot.json", timeout=30) as r:
            snap = json.loads(r.read())
        with urllib.request.urlopen(url, timeout=30) as r:
            assert b"snapshot.json" in r.read()
        stalled.close()
    finally:
        view.close()
    # the view reads the filter every READ_PERIOD_S of wall time: the snapshot is of some sample before the end
    assert 0 < snap["samples"] <= len(samples) and snap["running"] is True
    times = snap["history"]["time"]
    # (the history keeps its times rounded for the page: 6.52 beside the snapshot's 6.5200000000000005)
    assert times == sorted(times) and snap["time"] == pytest.approx(times[-1], abs=1e-9)
    assert times[-1] <= short_run.time[-1] + 1e-9
    assert len(snap["meter"]["share"]) == len(PARAMETER_NAMES)


@pytest.mark.parametrize(("text", "expected"), [("8080", ("127.0.0.1", 8080)), ("0.0.0.0:0", ("0.0.0.0", 0)),
                                                ("[::1]:9000", ("::1", 9000))])
def test_the_web_address(text, expected):
    from online_id.report.live import parse_address

    assert parse_address(text) == expected


def test_a_bad_web_address_is_one_line():
    from online_id.errors import OnlineIdError
    from online_id.report.live import parse_address

    with pytest.raises(OnlineIdError, match="--web host:port"):
        parse_address("host:port")
