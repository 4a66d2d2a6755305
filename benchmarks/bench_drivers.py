"""Decode-and-assemble throughput of online-id's frames, and a live listener's lag behind the bus.

Run: python benchmarks/bench_drivers.py [--live-seconds 20]

1. Throughput: a 60 s, 1 kHz simulated run encoded as online-id frames (4 per sample) is decoded through
   the DBC and assembled into samples; printed in frames per second against the 4000 frames/s a 1 kHz
   sample stream needs (the ratio is the headroom).
2. Lag: a run is replayed at real-time rate over python-can's udp_multicast from another process while
   this process decodes and estimates (EKF); the lag is the wall time at which a sample reached the
   estimator minus the kernel receive time of its last frame (python-can's timestamp on udp_multicast and
   SocketCAN), so it includes any queueing if the listener fell behind.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import random  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import _checkout  # noqa: E402, F401 -- this checkout's online_id, not an installed copy
import numpy as np  # noqa: E402
from online_id.drivers.assembler import FrameAssembler  # noqa: E402
from online_id.drivers.can_bus import CanBusSource, open_bus  # noqa: E402
from online_id.drivers.frames import frames_from_run, load_own_dbc  # noqa: E402
from online_id.drivers.signal_map import load_signal_map  # noqa: E402

from online_id.estimation import make_estimator, run_estimator  # noqa: E402
from online_id.io.tracklog import write_track_run  # noqa: E402
from online_id.sim.simulator import simulate  # noqa: E402
from online_id.vehicle import load_vehicle  # noqa: E402

NEEDED_FPS = 4000.0
PACING_P99_MS = 2.0  # the replayer's p99 lateness bound on a quiet machine


def throughput() -> None:
    car = load_vehicle("haro2008")
    run = simulate(car, car.truth("track")).run
    db = load_own_dbc()
    frames = list(frames_from_run(run, db))
    best = 0.0
    for _ in range(3):
        asm = FrameAssembler(db, load_signal_map("online_id"))
        t0 = time.perf_counter()
        n = sum(1 for f in frames if asm.feed(f) is not None)
        best = max(best, len(frames) / (time.perf_counter() - t0))
    print(f"decode+assemble: {best:,.0f} frames/s ({n} samples from {len(frames)} frames);"
          f" a 1 kHz stream needs {NEEDED_FPS:,.0f} frames/s: headroom {best / NEEDED_FPS:.0f}x")


def live_lag(seconds: float) -> None:
    car = load_vehicle("haro2008")
    run = simulate(car, car.truth("track"), duration_s=seconds, seed=2).run
    group, port = f"239.74.{random.randint(1, 254)}.{random.randint(1, 254)}", random.randint(40000, 49000)
    with tempfile.TemporaryDirectory() as tmp:
        log = write_track_run(run, Path(tmp) / "run.csv")
        bus = open_bus("udp_multicast", group, port=port)
        source = CanBusSource(bus, load_own_dbc(), load_signal_map("online_id"), idle_timeout_s=2.0, name="udp")
        player = subprocess.Popen([sys.executable, "-m", "online_id.cli.main", "replay", str(log), "--interface",
                                   "udp_multicast", "--channel", group, "--bus-arg", f"port={port}",
                                   "--json", str(Path(tmp) / "replay.json")],
                                  stdout=subprocess.PIPE, text=True)
        res = run_estimator(make_estimator(car, "ekf"), source)
        out, _ = player.communicate()
        source.close()
        timing = json.loads((Path(tmp) / "replay.json").read_text())
    lag = np.array(source.lag_s) * 1e3
    print(f"live over udp_multicast: {res.samples} samples in {res.sim_seconds:.1f} s; listener lag behind the"
          f" bus p50 {np.percentile(lag, 50):.3f} ms, p99 {np.percentile(lag, 99):.3f} ms,"
          f" max {lag.max():.3f} ms")
    print("replay: " + out.strip().splitlines()[-1])
    p99 = timing["lateness_p99_s"] * 1e3
    print(f"replay pacing: lateness p50 {timing['lateness_p50_s'] * 1e3:.3f} ms, p99 {p99:.3f} ms;"
          f" ratio to the {PACING_P99_MS:g} ms bound {p99 / PACING_P99_MS:.2f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--live-seconds", type=float, default=20.0, help="length of the live run (0 skips it)")
    args = ap.parse_args()
    throughput()
    if args.live_seconds > 0:
        live_lag(args.live_seconds)


if __name__ == "__main__":
    main()
