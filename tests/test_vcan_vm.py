"""The live CAN tests on a real SocketCAN vcan0.

Where the host has vcan0, tests/test_live.py runs its socketcan cases directly and this test has
nothing to add. Elsewhere (this project's machines: a kernel without CAN) it boots Debian's kernel
under qemu (tests/vm/harness.py), creates vcan0 in the guest and runs those same live tests there
against the host's checkout and virtual environment, sized to what emulated Python sustains.
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent / "vm"))
import harness  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
#: Under TCG emulation Python runs about 10x slower than on the host. A 100 Hz run (400 frames/s) of
#: 20 s keeps replay, decoding and the EKF in step with real time there and the whole VM run within
#: the suite's budget (replay lateness there: p99 about 4-6 ms; no test asserts it).
VM_RATE_HZ, VM_DURATION_S, VM_LOG_SECONDS = 100, 20, 8


def _portable_numba_cache(dest: Path) -> None:
    """Compile the EKF's numba loops (online_id/util/jit.py) on the host for a generic x86-64 CPU into ``dest``.

    numba's cache is keyed by the CPU: the guest's emulated CPU is another model, so it would compile them
    itself, minutes under TCG, in its tests' time; compiled here for ``generic`` (seconds) and copied into
    the guest's writable scratch space, the guest's processes load them (with NUMBA_CPU_NAME=generic too).
    """
    env = dict(os.environ, NUMBA_CPU_NAME="generic", NUMBA_CACHE_DIR=str(dest), OMP_NUM_THREADS="1")
    make_ekf = ("from online_id.estimation import make_estimator; from online_id.vehicle import load_vehicle; "
                "make_estimator(load_vehicle('haro2008'), 'ekf')")
    subprocess.run([sys.executable, "-c", make_ekf], cwd=REPO, env=env, check=True, timeout=600)


def test_live_tests_on_a_real_vcan0(record_bus, tmp_path):
    if harness.host_has_vcan0():
        pytest.skip("this host has vcan0: tests/test_live.py ran the socketcan cases on it directly")
    numba_cache = tmp_path / "numba-cache"
    _portable_numba_cache(numba_cache)
    env = {
        "PYTHONDONTWRITEBYTECODE": "1", "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1",
        "MPLCONFIGDIR": "/run/tmp/mpl", "ONLINE_ID_LIVE_RATE": str(VM_RATE_HZ),
        "ONLINE_ID_LIVE_DURATION": str(VM_DURATION_S), "ONLINE_ID_LIVE_LOG_SECONDS": str(VM_LOG_SECONDS),
        "PATH": os.environ.get("PATH", "/usr/bin:/bin"),
        "NUMBA_CPU_NAME": "generic", "NUMBA_CACHE_DIR": "/run/tmp/numba-cache",
    }
    exports = " ".join(f"{k}={shlex.quote(v)}" for k, v in env.items())
    script = f"""set -u
export {exports}
cd {shlex.quote(str(REPO))}
cp -r {shlex.quote(str(numba_cache))} /run/tmp/numba-cache
ip -details link show vcan0
echo "OID_TESTS_START=$(date +%s.%N)"
{shlex.quote(sys.executable)} -m pytest -p no:cacheprovider --color=no -q -rA -s --basetemp=/run/tmp/pytest-vm \\
    tests/test_live.py -k socketcan
rc=$?
echo "OID_TESTS_END=$(date +%s.%N)"
exit $rc
"""
    try:
        result = harness.run(script, timeout_s=900)
    except harness.VMError as exc:
        pytest.fail(str(exc))
    print(result.output)
    link = re.search(r"vcan0: <[^>]*UP[^>]*>", result.output)
    times = [float(x) for x in re.findall(r"OID_TESTS_(?:START|END)=([0-9.]+)", result.output)]
    tests_s = times[1] - times[0] if len(times) == 2 else float("nan")
    record_bus(f"socketcan:vcan0 inside a qemu VM (Debian kernel): boot {result.boot_s:.1f} s, tests in the"
               f" guest {tests_s:.1f} s, whole VM run {result.total_s:.1f} s")
    assert link, "the guest did not show vcan0 up"
    assert result.returncode == 0, result.output[-4000:]
    passed = re.search(r"(\d+) passed", result.output)
    assert passed and int(passed.group(1)) == 2, "both live tests must have run on vcan0 inside the VM"
    assert "skipped" not in result.output.split("short test summary")[-1].split("passed")[-1]
