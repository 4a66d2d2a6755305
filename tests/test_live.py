"""Live estimation across processes: one replays a simulated run at real-time rate onto a bus, the other
estimates from the bus. Runs on python-can's udp_multicast here, and on SocketCAN vcan0 where it exists
(the VM harness of issue 7 provides one on hosts without CAN)."""

from __future__ import annotations

import json
import math
import os
import random
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from online_id.vehicle import PARAMETER_NAMES


def _online_id(*args, **kw):
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    return subprocess.Popen([sys.executable, "-m", "online_id.cli.main", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, stdin=subprocess.DEVNULL, env=env, **kw)


#: Sized by the environment: the VM harness runs these under emulation, where Python is ~10x slower.
RATE_HZ = float(os.environ.get("ONLINE_ID_LIVE_RATE", "1000"))
DURATION_S = float(os.environ.get("ONLINE_ID_LIVE_DURATION", "60"))
LOG_SECONDS = float(os.environ.get("ONLINE_ID_LIVE_LOG_SECONDS", "20"))


def _vcan0_available() -> bool:
    if not hasattr(socket, "AF_CAN"):
        return False
    try:
        with socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW) as s:
            s.bind(("vcan0",))
        return True
    except OSError:
        return False


def _skip_without_vcan0(interface: str) -> None:
    if interface == "socketcan" and not _vcan0_available():
        pytest.skip("no SocketCAN vcan0 on this host (its kernel has no CAN); tests/test_vcan_vm.py runs this"
                    " test in a VM on a real vcan0")


def _buses():
    port = random.randint(40000, 49000)
    group = f"239.74.{random.randint(1, 254)}.{random.randint(1, 254)}"
    yield pytest.param(("udp_multicast", group, [f"port={port}"]), id="udp_multicast")
    yield pytest.param(("socketcan", "vcan0", []), id="socketcan-vcan0")


def replay_and_listen(tmp_path: Path, interface: str, channel: str, bus_args: list[str], log: Path,
                      speed: float = 1.0, listen_args: tuple[str, ...] = ()):
    extra = [a for b in bus_args for a in ("--bus-arg", b)]
    out = tmp_path / "live.json"
    listener = _online_id("listen", "--interface", interface, "--channel", channel, *extra, "--json", str(out),
                          "--idle-timeout", "5", "--start-timeout", "120", "--refresh", "10", *listen_args)
    ready = listener.stdout.readline()
    assert "listening on" in ready, ready
    time.sleep(0.5)
    player = _online_id("replay", str(log), "--interface", interface, "--channel", channel, *extra,
                        "--speed", str(speed), "--json", str(tmp_path / "replay.json"))
    replay_out, _ = player.communicate(timeout=600)
    listen_out, _ = listener.communicate(timeout=120)
    assert player.returncode == 0, replay_out
    assert listener.returncode == 0, listen_out
    return json.loads(out.read_text()), json.loads((tmp_path / "replay.json").read_text()), replay_out, listen_out


@pytest.mark.parametrize("bus", list(_buses()))
def test_live_estimate_over_a_bus_matches_the_csv_estimate(tmp_path, bus, record_bus):
    interface, channel, bus_args = bus
    _skip_without_vcan0(interface)
    record_bus(f"{interface}:{channel} {' '.join(bus_args)}".strip() + f" ({RATE_HZ:g} Hz, {DURATION_S:g} s run)")
    log = tmp_path / "run.csv"
    from online_id.cli.main import main

    assert main(["simulate", "--out", str(log), "--duration", f"{DURATION_S:g}", "--rate", f"{RATE_HZ:g}",
                 "--seed", "5"]) == 0
    n = int(round(DURATION_S * RATE_HZ))
    ref = tmp_path / "ref.json"
    assert main(["estimate", str(log), "--quiet", "--no-polish", "--json", str(ref)]) == 0  # the filter alone, as live
    live, timing, replay_out, listen_out = replay_and_listen(tmp_path, interface, channel, bus_args, log)
    print(replay_out)
    print(listen_out[-2000:])
    frames = live["source_report"]["frames"]
    print(f"replay: {timing['frames']} frames, lateness p50 {timing['lateness_p50_s'] * 1e3:.3f} ms,"
          f" p99 {timing['lateness_p99_s'] * 1e3:.3f} ms; listener: {frames['frames']} frames, {live['samples']}"
          f" samples")
    assert timing["frames"] == 4 * n, timing  # the player sent every frame, in order
    assert frames["frames"] == live["frames_received"] <= 4 * n, frames
    assert frames["unknown_frames"] == 0
    assert live["source_report"]["ended_by"].startswith("end of stream")
    reference = json.loads(ref.read_text())
    if frames["frames"] == 4 * n:
        # Nothing lost. Pacing is the machine's (benchmarks/bench_drivers.py measures it): a replayer held up
        # >0.1 s inside a sample makes that sample's early frames stale. Every sample is made or counted.
        assert live["samples"] == frames["samples"] == n - frames["incomplete_samples"], frames
        assert frames["incomplete_samples"] <= n // 100, frames
        assert not frames["counter_mismatch"]
        worst = max(abs(live["parameters"][p]["value"] / reference["parameters"][p]["value"] - 1)
                    for p in PARAMETER_NAMES)
        print(f"largest difference between live and CSV estimates: {100 * worst:.4f} %")
        assert worst < 0.01, (live["parameters"], reference["parameters"])
    else:
        # A listener that cannot keep up (both cores busy elsewhere) loses datagrams: UDP does not wait. What
        # must hold on any machine: the loss is counted and said, and it costs information, never a bias.
        print(f"lost {live['lost_samples']} samples ({100 * live['lost_samples_fraction']:.1f} %), frames lost"
              f" {live['lost_frames_by_message']}")
        assert live["lost_samples"] > 0 and "sample(s) lost" in listen_out, listen_out[-2000:]
        assert live["lost_samples"] <= n - live["samples"]
        assert live["lost_by_signal"]["yaw_rate"] >= live["lost_samples"]
        z = {p: (live["parameters"][p]["value"] - reference["parameters"][p]["value"])
             / math.hypot(live["parameters"][p]["std"], reference["parameters"][p]["std"]) for p in PARAMETER_NAMES}
        print("live against direct, in combined σ: " + ", ".join(f"{p} {v:+.2f}" for p, v in z.items()))
        assert max(abs(v) for v in z.values()) < 3, z


@pytest.mark.parametrize("bus", list(_buses()))
def test_a_real_can_log_replayed_and_decoded_through_its_dbc(tmp_path, bus, record_bus, rav4_paths):
    """The RAV4 log's can0 frames (first LOG_SECONDS s) replayed onto the bus, decoded live through the
    car's DBC and signal map: every frame arrives and every KINEMATICS frame makes a sample."""
    import can

    interface, channel, bus_args = bus
    _skip_without_vcan0(interface)
    record_bus(f"{interface}:{channel} {' '.join(bus_args)}".strip() + f" (RAV4 CAN log, {LOG_SECONDS:g} s)")
    log, dbc = rav4_paths
    cut = tmp_path / "rav4_cut.log"
    frames = [m for m in can.LogReader(str(log)) if m.channel == "can0"]
    frames = [m for m in frames if m.timestamp - frames[0].timestamp < LOG_SECONDS]
    with can.Logger(str(cut)) as writer:
        for m in frames:
            writer.on_message_received(m)
    kinematics = sum(1 for m in frames if m.arbitration_id == 0x24)
    live, timing, replay_out, listen_out = replay_and_listen(
        tmp_path, interface, channel, bus_args, cut,
        listen_args=("--dbc", str(dbc), "--signals", "toyota_rav4_2017", "--vehicle", "rav4_2017"))
    print(replay_out)
    rep = live["source_report"]["frames"]
    print(f"replay: {timing['frames']} frames; listener: {rep['frames']} frames, {live['samples']} samples,"
          f" {rep['unknown_frames']} frames of unmapped IDs")
    assert timing["frames"] == len(frames) and rep["frames"] == len(frames)
    assert live["samples"] == kinematics and rep["samples"] == kinematics
    # the map uses KINEMATICS, STEER_ANGLE_SENSOR and SPEED; every other ID is counted as unmapped
    assert rep["unknown_frames"] == sum(1 for m in frames if m.arbitration_id not in (0x24, 0x25, 0xB4))
    assert not live["source_report"]["frames"]["wrong_length"]


#: The stress test's bus: its own port range, so it never crosses another test's stream.
STRESS_PORTS = (43200, 43299)
#: Busy processes beside the replay: as many as this machine has cores.
STRESS_LOAD = os.cpu_count() or 2


def _busy(seconds: float) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-c", f"import time\nend = time.time() + {seconds}\n"
                             "while time.time() < end:\n    pass\n"])


def test_a_fast_replay_under_cpu_load_reports_its_loss_and_stays_within_3_sigma(tmp_path, record_bus):
    """Issue 17: a 20 s run replayed at 5x (20,000 frames/s) while every core is kept busy. Whatever the
    listener loses is reported (lost_samples, per signal, frame counts), and the estimate stays within 3
    combined σ of the estimate of the same log read directly: a loss costs information, never a bias.
    (Before: 23 % of the samples lost unreported, Mzz 26 % off, marked informed.)"""
    port = random.randint(*STRESS_PORTS)
    group = f"239.74.{random.randint(1, 254)}.{random.randint(1, 254)}"
    record_bus(f"udp_multicast:{group} port={port} (20 s run at 5x under {STRESS_LOAD} busy processes)")
    log = tmp_path / "run.csv"
    from online_id.cli.main import main

    assert main(["simulate", "--out", str(log), "--duration", "20", "--seed", "7"]) == 0
    ref = tmp_path / "ref.json"
    assert main(["estimate", str(log), "--quiet", "--no-polish", "--json", str(ref)]) == 0  # the filter alone, as live
    load = [_busy(15) for _ in range(STRESS_LOAD)]
    try:
        live, timing, _, listen_out = replay_and_listen(tmp_path, "udp_multicast", group, [f"port={port}"], log,
                                                        speed=5.0)
    finally:
        for p in load:
            p.kill()
            p.wait()
    frames = live["source_report"]["frames"]
    print(listen_out[-1500:])
    print(f"received {live['frames_received']} of {timing['frames']} frames, {live['samples']} samples;"
          f" lost {live['lost_samples']} samples ({100 * live['lost_samples_fraction']:.1f} %), frames lost"
          f" {live['lost_frames_by_message']}; receive buffer {live['source_report']['receive_buffer_bytes']} B")
    missing_samples = 20_000 - live["samples"]
    if missing_samples:  # lost: the count must say so (counted from the first sample to the last received)
        assert live["lost_samples"] > 0 and "sample(s) lost" in listen_out
        assert live["lost_samples"] <= missing_samples
        assert live["lost_by_signal"]["yaw_rate"] >= live["lost_samples"]
    else:
        assert live["lost_samples"] == 0 and live["frames_received"] == timing["frames"] == 80_000
    assert frames["frames"] == live["frames_received"]
    reference = json.loads(ref.read_text())
    z = {p: (live["parameters"][p]["value"] - reference["parameters"][p]["value"])
         / math.hypot(live["parameters"][p]["std"], reference["parameters"][p]["std"]) for p in PARAMETER_NAMES}
    print("live against direct, in combined σ: " + ", ".join(f"{p} {v:+.2f}" for p, v in z.items()))
    assert max(abs(v) for v in z.values()) < 3, z


def test_listen_with_nothing_on_the_bus_exits_2_after_the_start_timeout(tmp_path):
    port = random.randint(*STRESS_PORTS)
    out = tmp_path / "live.json"
    listener = _online_id("listen", "--interface", "udp_multicast", "--channel", "239.74.254.253",
                          "--bus-arg", f"port={port}", "--start-timeout", "1", "--json", str(out))
    text, _ = listener.communicate(timeout=120)
    assert listener.returncode == 2, text
    assert "Traceback" not in text
    assert "no frame arrived within --start-timeout 1 s" in text
    assert json.loads(out.read_text())["samples"] == 0  # what there is (nothing) is still written


def test_listen_learns_a_steering_delay_and_offsets_as_the_csv_estimate_does(tmp_path, record_bus, capsys):
    """Issue 25: ``listen --effect steering_delay --offsets`` over udp_multicast on a car that steers 60 ms
    late (30 s at 500 Hz, replayed at 2x): the extra states are in the live table and the JSON, and every
    parameter, the delay and the offsets lie within 3 combined σ of the CSV estimate of the same run (the
    filter alone, as live). A delay holds each sample until the late channels have arrived; the end of the
    stream works the rest, so the live run counts every sample the bus gave. Costs about 25 s."""
    port = random.randint(*STRESS_PORTS)
    group = f"239.74.{random.randint(1, 254)}.{random.randint(1, 254)}"
    record_bus(f"udp_multicast:{group} port={port} (30 s at 500 Hz with a 60 ms steering delay, at 2x)")
    log = tmp_path / "run.csv"
    from online_id.cli.main import main

    assert main(["simulate", "--out", str(log), "--duration", "30", "--rate", "500", "--seed", "11",
                 "--effect", "steering_delay=0.06"]) == 0
    flags = ("--effect", "steering_delay", "--offsets")
    ref = tmp_path / "ref.json"
    assert main(["estimate", str(log), "--quiet", "--no-polish", "--json", str(ref), *flags]) == 0
    capsys.readouterr()
    live, timing, _, listen_out = replay_and_listen(tmp_path, "udp_multicast", group, [f"port={port}"], log,
                                                    speed=2.0, listen_args=flags)
    print(listen_out[-2500:])
    reference = json.loads(ref.read_text())
    assert live["samples"] == live["source_report"]["frames"]["samples"]
    assert "[effect steering_delay delay_s:" in listen_out  # the live table's line (not a terminal)
    assert "effect steering_delay delay_s:" in listen_out.split("samples from")[-1]  # the final table
    pairs = [(p, live["parameters"][p], reference["parameters"][p]) for p in PARAMETER_NAMES]
    pairs.append(("delay_s", live["effects"]["steering_delay"]["delay_s"],
                  reference["effects"]["steering_delay"]["delay_s"]))
    pairs += [(f"offset {c}", live["offsets"][c], reference["offsets"][c]) for c in reference["offsets"]]
    z = {name: (a["value"] - b["value"]) / math.hypot(a["std"], b["std"]) for name, a, b in pairs}
    print("live against the CSV, in combined σ: " + ", ".join(f"{k} {v:+.2f}" for k, v in z.items()))
    assert max(abs(v) for v in z.values()) < 3, z
    assert abs(live["effects"]["steering_delay"]["delay_s"]["value"] / 0.06 - 1) < 0.1
