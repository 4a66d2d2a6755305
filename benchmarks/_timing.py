"""Timing a whole command from outside, as a user waits for it (start-up included)."""

from __future__ import annotations

import resource
import subprocess
import time


def timed(cmd: list[str], env: dict, cwd) -> tuple[float, float]:
    """(wall [s], CPU [s]: user + system of the child) of one run of ``cmd``, its output thrown away."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env, cwd=cwd)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
