"""A live run of hours in bounded memory (issue 40): what it keeps per sample is bounded, whatever its length.

The trace goes to its file as it comes (the same bytes as the trace written at the end) while memory keeps an
evenly thinned copy; the live page's history is thinned to a bound; the lag percentiles come from a bounded
sample. Memory over a long run is measured by ``benchmarks/bench_soak.py``; these tests check the structures.
"""

from __future__ import annotations

import io
import os
from pathlib import Path

import numpy as np
import pytest

from online_id.estimation import make_estimator, run_estimator
from online_id.sim.simulator import simulate
from online_id.stream.samples import MEASURED_CHANNELS, samples_from_run
from online_id.tracing import ROW_WIDTH, STREAM_BLOCK_ROWS, StreamedTrace, TraceRows
from online_id.util.decimated import DecimatedRows
from online_id.util.reservoir import Reservoir
from online_id.vehicle import load_vehicle

CAR = load_vehicle("haro2008")


@pytest.mark.parametrize("offered", [1, 7, 8, 9, 100, 1001])
def test_decimated_rows_keep_an_even_subset_within_the_bound_with_the_first_and_the_last(offered):
    history = DecimatedRows(8, 2)
    for k in range(offered):
        history.add([k, -k])
    rows = history.rows()
    kept = rows[:, 0].astype(int).tolist()
    assert len(rows) == len(history) <= 8 + 1
    assert kept[0] == 0 and kept[-1] == offered - 1  # the whole span, to the present
    evenly = kept[:-1] if (offered - 1) % history.stride else kept
    assert evenly == list(range(0, offered, history.stride))  # every stride-th row, nothing else
    if offered > 8:
        assert len(evenly) >= 4  # thinned to between half the bound and the bound
    np.testing.assert_array_equal(rows[:, 1], -rows[:, 0])
    np.testing.assert_array_equal(history.last, [offered - 1, 1 - offered])


def test_a_reservoir_keeps_every_value_to_its_capacity_then_a_uniform_sample_of_that_size():
    lag = Reservoir(capacity=1000)
    for x in range(500):
        lag.append(float(x))
    assert len(lag) == 500 and np.array_equal(np.array(lag), np.arange(500.0))
    for x in range(500, 100_000):
        lag.append(float(x))
    kept = lag.values()
    assert len(kept) == 1000 and lag.seen == 100_000
    assert abs(np.median(kept) - 50_000) < 5_000  # a uniform sample of the whole stream, not its start
    assert kept.min() < 10_000 and kept.max() > 90_000


def _rows(n):
    rng = np.random.default_rng(1)
    return [(0.01 * k, rng.uniform(1e3, 1e5, 8), rng.uniform(1, 100, 8), 22.2, np.nan if k % 3 else 1.5)
            for k in range(n)]


def test_a_streamed_trace_writes_the_bytes_of_the_trace_written_at_the_end_and_keeps_a_bounded_copy(tmp_path):
    rows = _rows(3 * STREAM_BLOCK_ROWS + 17)
    whole, stream = TraceRows(), io.StringIO()
    streamed = StreamedTrace(stream, keep=10)
    for k, row in enumerate(rows):
        whole.add(*row)
        streamed.add(*row)
        if k == STREAM_BLOCK_ROWS - 2:
            assert stream.getvalue().count("\n") == 1  # the header; rows go in blocks
        if k == STREAM_BLOCK_ROWS - 1:
            assert stream.getvalue().count("\n") == 1 + STREAM_BLOCK_ROWS  # a block written and flushed
    streamed.flush()
    from online_id.estimation import EstimateTrace
    from online_id.tracing import columns

    t, v, s, speed, ay = columns(whole.rows())
    EstimateTrace(t, v, s, speed, ay).write_csv(tmp_path / "trace.csv")
    assert stream.getvalue() == (tmp_path / "trace.csv").read_text()  # the format scripts read, byte for byte
    assert streamed.written == len(rows) == len(streamed)
    kept = streamed.rows()
    assert kept.shape[1] == ROW_WIDTH and len(kept) <= 10 + 1  # memory: the thinned copy only
    np.testing.assert_array_equal(kept[0], whole.rows()[0])
    np.testing.assert_array_equal(kept[-1], whole.rows()[-1])


def test_a_streamed_trace_without_a_file_keeps_the_thinned_copy_only():
    streamed = StreamedTrace(None, keep=4)
    for row in _rows(50):
        streamed.add(*row)
    streamed.flush()
    assert streamed.written == 0 and len(streamed.rows()) <= 5


def test_run_estimator_streams_the_trace_it_would_keep_and_returns_a_thinned_copy(tmp_path):
    """The per-sample loop a live run uses (on_sample given): the file is the whole trace, row for row, as
    the in-memory trace of the same run; ``result.trace`` holds at most the bound, first and last exact."""
    run = simulate(CAR, CAR.truth("track"), duration_s=2.0, seed=4).run
    samples = list(samples_from_run(run))
    whole = run_estimator(make_estimator(CAR, "ekf"), samples, on_sample=lambda est, sample: None)
    whole.trace.write_csv(tmp_path / "whole.csv")
    with (tmp_path / "streamed.csv").open("w", encoding="utf-8") as fh:
        thin = run_estimator(make_estimator(CAR, "ekf"), samples, on_sample=lambda est, sample: None,
                             trace_rows=StreamedTrace(fh, keep=16))
    assert (tmp_path / "streamed.csv").read_bytes() == (tmp_path / "whole.csv").read_bytes()
    assert len(whole.trace.time) > 100 and len(thin.trace.time) <= 17
    assert thin.trace.time[0] == whole.trace.time[0] and thin.trace.time[-1] == whole.trace.time[-1]
    np.testing.assert_array_equal(thin.trace.values[-1], whole.trace.values[-1])
    assert thin.samples == whole.samples and thin.sim_seconds == whole.sim_seconds
    np.testing.assert_array_equal(thin.parameters.to_vector(), whole.parameters.to_vector())


def test_the_live_page_keeps_a_bounded_evenly_thinned_history_to_the_present(monkeypatch):
    from types import SimpleNamespace

    from online_id.report import live

    monkeypatch.setattr(live, "READ_PERIOD_S", 0.0)  # a history point per sample
    monkeypatch.setattr(live, "MAX_HISTORY", 64)
    view = live.LiveView("test")
    view._next_verdict = float("inf")  # (the verdict is judge_estimator's, tested with it)
    theta = CAR.prior.to_vector()
    est = SimpleNamespace(parameters=CAR.prior, parameter_std=0.1 * theta)
    n = 1000
    for k in range(n):
        view(est, SimpleNamespace(time=0.001 * k, speed=20.0))
    snap = view.snapshot()
    t = np.array(snap["history"]["time"])
    assert len(t) <= 64 + 1 and t[0] == 0.0 and t[-1] == pytest.approx(0.001 * (n - 1))
    steps = np.diff(t[:-1])
    assert np.allclose(steps, steps[0])  # evenly spaced over the whole run, not dense at its end only
    assert snap["samples"] == n


def test_listen_streams_its_trace_into_a_partial_file_renamed_at_the_end(tmp_path):
    from online_id.cli.outputs import Outputs, StreamedOutput

    target = tmp_path / "live.csv"
    out = StreamedOutput("--trace", target)
    out.file.write("time\n")
    out.file.flush()
    assert (tmp_path / "live.csv.partial").read_text() == "time\n" and not target.exists()  # readable as it grows
    assert out.finish(Outputs(announce=False)) and target.read_text() == "time\n"
    assert not (tmp_path / "live.csv.partial").exists()
    gone = StreamedOutput("--trace", tmp_path / "other.csv")
    gone.discard()
    assert not list(tmp_path.glob("other.csv*"))
    if os.path.exists("/dev/null"):  # a device is written in place, never renamed onto
        dev = StreamedOutput("--trace", "/dev/null")
        assert dev.partial == dev.path and dev.finish(Outputs(announce=False))


def test_a_listener_behind_its_bus_holds_a_bounded_backlog_and_loses_nothing_when_it_catches_up(monkeypatch):
    """The reader thread stops draining the bus at MAX_BACKLOG_FRAMES waiting for the estimator (frames then
    wait in the bus's own buffer: a socket's, where the kernel drops what does not fit, counted as lost)."""
    import time

    import can
    import online_id.drivers.can_bus as can_bus
    from online_id.drivers.frames import frames_from_run, load_own_dbc
    from online_id.drivers.signal_map import load_signal_map

    monkeypatch.setattr(can_bus, "MAX_BACKLOG_FRAMES", 600)
    channel = f"backlog-{time.monotonic_ns()}"
    rx = can.Bus(interface="virtual", channel=channel, preserve_timestamps=True)
    tx = can.Bus(interface="virtual", channel=channel, preserve_timestamps=True)
    problems = []
    source = can_bus.CanBusSource(rx, load_own_dbc(), load_signal_map("online_id"), name="virtual",
                                  idle_timeout_s=1.0, on_problem=problems.append)
    frames = list(frames_from_run(simulate(CAR, CAR.truth("track"), duration_s=1.0, seed=2).run))
    for f in frames:
        tx.send(f)
    samples = iter(source)
    first = next(samples)  # the reader runs; the estimator is held up here
    deadline = time.monotonic() + 30
    while source.backlog_stops == 0 and time.monotonic() < deadline:
        time.sleep(0.01)
    held = source._frames_read - source._frames_taken
    assert source.backlog_stops > 0 and held <= 600 + can_bus.READ_BATCH, held
    rest = list(samples)  # caught up: the frames that waited on the bus are read then (the end: 1 s idle)
    tx.shutdown()
    rx.shutdown()
    assert 1 + len(rest) == len(frames) // 4 and source.assembler.stats.lost_samples == 0
    assert first.time == 0.0 and any("behind the bus" in p for p in problems), problems


def test_the_innovation_log_is_read_without_a_copy_until_it_wraps_and_keeps_its_rows_after():
    """A live verdict reads the filter's innovation log every second: its rows are a read-only view of the log
    (no copy of up to 16 MB each time) until it wraps, the same values after it wrapped."""
    from online_id.filters.innovations import InnovationLog

    log = InnovationLog(capacity=3000)
    channels = np.array([0, 2])
    for k in range(2500):
        log.record(float(k), channels, np.array([k, -k], dtype=float), np.ones(2), k > 10)
    rows = log.rows()
    assert not rows.flags.writeable and np.shares_memory(rows, log._rows)
    width = 2 + 2 * len(MEASURED_CHANNELS)  # time, converged, ν and R ratio of each channel
    assert rows.shape == (2500, width) and rows[-1, 0] == 2499 and rows[-1, 2] == 2499 and np.isnan(rows[-1, 3])
    for k in range(2500, 3500):  # wraps: the oldest 500 forgotten
        log.record(float(k), channels, np.array([k, -k], dtype=float), np.ones(2), True)
    wrapped = log.rows()
    assert wrapped.shape == (3000, width) and wrapped[0, 0] == 500 and wrapped[-1, 0] == 3499
    np.testing.assert_array_equal(wrapped[:, 0], np.arange(500.0, 3500.0))


def _resident_kb() -> int | None:
    try:
        status = Path("/proc/self/status").read_text()
    except OSError:
        return None
    return next(int(line.split()[1]) for line in status.splitlines() if line.startswith("VmRSS:"))


def test_a_new_innovation_log_holds_no_memory_until_rows_are_written():
    """Its whole capacity (16 MB) is allocated at once but not written: a short run pays nothing for it
    (issue 26), and a long one grows by the rows it records, never by a copy made to grow (issue 40)."""
    from online_id.filters.innovations import InnovationLog

    before = _resident_kb()
    if before is None:
        pytest.skip("no /proc/self/status on this system")
    log = InnovationLog()
    assert _resident_kb() - before < 2048  # kB: not the 16 MB of its capacity
    rows = 20_000
    for k in range(rows):
        log.record(float(k), np.array([0, 1, 2, 3]), np.zeros(4), np.ones(4), True)
    written_kb = rows * log._rows.itemsize * log._rows.shape[1] / 1024  # 1.6 MB
    assert _resident_kb() - before < written_kb + 2048
