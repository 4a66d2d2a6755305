"""Start-up: how long a command takes before its first sample (issue 26: under 0.5 s).

Run: python benchmarks/bench_startup.py [--repeat 7]

Each command runs as a fresh process, ``--repeat`` times, alternating with the others so that drift hits
all alike; printed: median and minimum wall time and the median CPU time (user + system, which a busy
machine disturbs less than wall time), and each median's ratio to the baseline, a bare
``python -c "import numpy, scipy.linalg"`` (what any numerical command pays):

- ``online-id --version``: the CLI itself;
- ``estimate`` of a 0.2 s, 1 kHz run (200 samples) with ``--no-polish``: reading the log, building the
  filter (imports, numba's cache) and the first samples: the time to the first sample, within a few ms;
- the same with ``--filter ukf``.

Python's bytecode cache is warm, as numba's is: the runs do not inherit ``PYTHONDONTWRITEBYTECODE`` (set in
some sandboxes and containers), so the warm-up writes the package's ``__pycache__`` as an installed
package has it (pip compiles it at install) and as any checkout gets it at its first run. Without it
each run compiles the package's sources again, about 0.07 s of CPU that no user waits for.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import _checkout
from _timing import timed

ROOT = Path(_checkout.ROOT)
TARGET_S = 0.5  # issue 26: start-up to the first sample


def _timed(cmd: list[str], env: dict) -> tuple[float, float]:
    """(wall [s], CPU [s]) of one run of ``cmd`` from the checkout's root."""
    return timed(cmd, env, ROOT)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=7)
    args = ap.parse_args()
    env = dict(os.environ, PYTHONPATH=str(ROOT), OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    env.pop("PYTHONDONTWRITEBYTECODE", None)  # the bytecode cache warm, as an installed package's (docstring)
    py = sys.executable
    cli = [py, "-m", "online_id.cli.main"]
    with tempfile.TemporaryDirectory() as tmp:
        run = Path(tmp) / "tiny.csv"
        subprocess.run([*cli, "simulate", "--out", str(run), "--duration", "0.2", "--rate", "1000"], check=True,
                       stdout=subprocess.DEVNULL, env=env, cwd=ROOT)
        commands = {
            "baseline: import numpy, scipy.linalg": [py, "-c", "import numpy, scipy.linalg"],
            "online-id --version": [*cli, "--version"],
            "estimate 200 samples (EKF)": [*cli, "estimate", str(run), "--no-polish", "--quiet"],
            "estimate 200 samples (UKF)": [*cli, "estimate", str(run), "--no-polish", "--quiet", "--filter", "ukf"],
        }
        for cmd in commands.values():  # numba's cache, Python's bytecode cache and the OS's file cache warm
            _timed(cmd, env)
        times: dict[str, list[tuple[float, float]]] = {k: [] for k in commands}
        for _ in range(args.repeat):
            for name, cmd in commands.items():
                times[name].append(_timed(cmd, env))
    base = statistics.median(w for w, _ in times["baseline: import numpy, scipy.linalg"])
    base_cpu = statistics.median(c for _, c in times["baseline: import numpy, scipy.linalg"])
    print(f"{'command':<40} {'median':>8} {'min':>8} {'CPU':>8} {'÷ base':>7} {'CPU ÷ base':>10}")
    for name, rows in times.items():
        wall = statistics.median(w for w, _ in rows)
        cpu = statistics.median(c for _, c in rows)
        print(f"{name:<40} {wall:>7.3f}s {min(w for w, _ in rows):>7.3f}s {cpu:>7.3f}s {wall / base:>7.2f}"
              f" {cpu / base_cpu:>10.2f}")
    ekf = statistics.median(w for w, _ in times["estimate 200 samples (EKF)"])
    print(f"start-up to the first sample (EKF estimate, median): {ekf:.3f} s; target {TARGET_S:g} s:"
          f" {'met' if ekf <= TARGET_S else 'not met'} (n = {args.repeat})")


if __name__ == "__main__":
    main()
