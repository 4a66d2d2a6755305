"""SIGTERM, SIGHUP and SIGINT end `estimate`, `listen` and `fit` with what was reached written and marked
interrupted, and exit status 128 + the signal (issue 17)."""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from online_id.cli.main import main
from online_id.vehicle import PARAMETER_NAMES

#: How long a child gets to show it has started, or to end after the signal [s] (generous: shared machine).
START_TIMEOUT_S = 120
END_TIMEOUT_S = 60


def _start(*args) -> subprocess.Popen:
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", PYTHONUNBUFFERED="1")
    return subprocess.Popen([sys.executable, "-m", "online_id.cli.main", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, stdin=subprocess.DEVNULL, env=env, text=True, bufsize=1)


class _Watch:
    """Reads a child's stdout and stderr in the background; waits until a text has appeared in either."""

    def __init__(self, proc: subprocess.Popen):
        self.proc, self.text, self._lock = proc, {"out": "", "err": ""}, threading.Lock()
        self._threads = [threading.Thread(target=self._pump, args=(s, k), daemon=True)
                         for s, k in ((proc.stdout, "out"), (proc.stderr, "err"))]
        for t in self._threads:
            t.start()

    def _pump(self, stream, key):
        while True:
            chunk = stream.read(1) if key == "err" else stream.readline()  # tqdm writes \r, not lines
            if not chunk:
                return
            with self._lock:
                self.text[key] += chunk

    def wait_for(self, needle: str, timeout: float = START_TIMEOUT_S) -> None:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            with self._lock:
                if needle in self.text["out"] or needle in self.text["err"]:
                    return
            if self.proc.poll() is not None:
                break
            time.sleep(0.05)
        self.proc.kill()
        pytest.fail(f"{needle!r} never appeared (exit {self.proc.poll()}):\n{self.text}")

    def finish(self) -> tuple[int, str, str]:
        rc = self.proc.wait(timeout=END_TIMEOUT_S)
        for t in self._threads:
            t.join(timeout=5)
        # (closed here: a pipe left to the garbage collector raised its ResourceWarning inside a later test's
        # in-process command, which printed it as a second line of its one-line error)
        self.proc.stdout.close()
        self.proc.stderr.close()
        return rc, self.text["out"], self.text["err"]


@pytest.fixture(scope="module")
def long_run(tmp_path_factory) -> Path:
    """A 240 s run at 1 kHz: estimating it takes several seconds even on a fast machine, so a signal sent
    once the progress shows lands in the middle of the run."""
    path = tmp_path_factory.mktemp("long") / "run.csv"
    assert main(["simulate", "--out", str(path), "--duration", "240", "--seed", "3"]) == 0
    return path


def _check_interrupted_outputs(json_path: Path, trace_path: Path | None, total_samples: int) -> dict:
    data = json.loads(json_path.read_text())
    assert data["interrupted"] is True
    assert set(PARAMETER_NAMES) <= set(data["parameters"])
    if trace_path is not None:
        lines = trace_path.read_text().splitlines()
        assert lines[0].startswith("time,Mzz,Mzz_std") and len(lines) > 2
    if total_samples:
        assert 0 < data["samples"] < total_samples  # stopped in the middle, with what it had
    return data


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGHUP], ids=["SIGTERM", "SIGHUP"])
def test_estimate_ended_by_a_signal_writes_json_and_trace(tmp_path, long_run, signum):
    out, trace = tmp_path / "est.json", tmp_path / "trace.csv"
    proc = _start("estimate", str(long_run), "--json", str(out), "--trace", str(trace))
    watch = _Watch(proc)
    watch.wait_for("k/240k")  # the progress bar has counted a thousand samples: the filter is running
    proc.send_signal(signum)
    rc, stdout, stderr = watch.finish()
    assert rc == 128 + signum, (stdout, stderr)
    assert "Traceback" not in stderr
    assert "estimate" in stdout and "wrote" in stdout  # the table was printed, then the files written
    assert stdout.index("Mzz") < stdout.index(f"wrote {out}")
    _check_interrupted_outputs(out, trace, 240_000)


def test_fit_interrupted_keeps_its_best_candidate(tmp_path, long_run):
    short = tmp_path / "run.csv"
    assert main(["simulate", "--out", str(short), "--duration", "20", "--seed", "3"]) == 0
    out = tmp_path / "fit.json"
    proc = _start("fit", str(short), "--json", str(out), "--generations", "100000")
    watch = _Watch(proc)
    watch.wait_for("cost ")  # the GA's progress shows its best cost: it has started
    time.sleep(1.0)  # a few generations further than the first
    proc.send_signal(signal.SIGINT)
    rc, stdout, stderr = watch.finish()
    assert rc == 130, (stdout, stderr)
    assert "Traceback" not in stderr
    data = _check_interrupted_outputs(out, None, 0)
    assert data["choice"].startswith("interrupted")
    assert data["cost"] > 0 and all(data["parameters"][n]["value"] > 0 for n in PARAMETER_NAMES)


def test_listen_ended_by_sigterm_writes_json_and_trace(tmp_path, long_run):
    bus = ["--interface", "udp_multicast", "--channel", f"239.74.{random.randint(1, 254)}.{random.randint(1, 254)}",
           "--bus-arg", f"port={random.randint(43200, 43299)}"]
    out, trace = tmp_path / "live.json", tmp_path / "live.csv"
    listener = _start("listen", *bus, "--json", str(out), "--trace", str(trace), "--start-timeout", "120")
    watch = _Watch(listener)
    watch.wait_for("listening on")
    player = subprocess.Popen([sys.executable, "-m", "online_id.cli.main", "replay", str(long_run), *bus,
                               "--no-priority"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                              stdin=subprocess.DEVNULL)
    try:
        watch.wait_for("t = ")  # the live table's first line: samples are being estimated
        time.sleep(0.5)
        listener.send_signal(signal.SIGTERM)
        rc, stdout, stderr = watch.finish()
    finally:
        player.terminate()
        player.wait(timeout=END_TIMEOUT_S)
    assert rc == 143, (stdout, stderr)
    assert "Traceback" not in stderr
    data = _check_interrupted_outputs(out, trace, 240_000)
    assert data["source_report"]["ended_by"] == "interrupted"
    assert "lost_samples" in data and "frames_received" in data


def test_diagnose_ended_by_sigterm_keeps_the_base_fit_and_the_candidates_so_far(tmp_path):
    log = tmp_path / "run.csv"
    # 25 s: the held-out data are every 4th 5 s segment, so a run of 15 s or less has none
    assert main(["simulate", "--out", str(log), "--duration", "25", "--seed", "3"]) == 0
    out = tmp_path / "d.json"
    proc = _start("diagnose", str(log), "--json", str(out))
    watch = _Watch(proc)
    watch.wait_for("[3/")  # the base model and one candidate are fitted
    proc.send_signal(signal.SIGTERM)
    rc, stdout, stderr = watch.finish()
    assert rc == 143, (stdout, stderr)
    assert "Traceback" not in stderr
    data = json.loads(out.read_text())
    assert data["interrupted"] is True and data["base_model"]["held_out_cost"] > 0
    assert 1 <= len(data["effects"]) < 5
