"""The race log's default estimate against its ``--no-polish`` run (issue 26: within 2×).

Run: python benchmarks/bench_race_polish.py [--repeat 3] [--intersample hold|linear|cubic]

Both commands run as fresh processes (start-up included: it is what a user waits for), in turn, ``--repeat``
times; the ratio is taken pair by pair (the machine's speed drifts) and its median printed, with each
command's median wall and CPU time and what the polish said (a polish that will not converge stops within
a few evaluations: :class:`online_id.batchfit.polish.PolishFailsFast`). ``--intersample`` is handed to both
commands (the filter's and the polish's steering between samples).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
from pathlib import Path

import _checkout
from _timing import timed

ROOT = Path(_checkout.ROOT)
RACE = ROOT.parent / "shared" / "realdata" / "revs_250lm" / "revs_250lm_laps_0-400s.csv"
TARGET = 2.0  # issue 26: the default estimate within 2x its --no-polish time


def _timed(cmd: list[str], env: dict) -> tuple[float, float]:
    """(wall [s], CPU [s]) of one run of ``cmd`` from the checkout's root."""
    return timed(cmd, env, ROOT)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--log", type=Path, default=RACE)
    ap.add_argument("--intersample", choices=("hold", "linear", "cubic"), default=None)
    args = ap.parse_args()
    env = dict(os.environ, PYTHONPATH=str(ROOT), OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    cli = [sys.executable, "-m", "online_id.cli.main", "estimate", str(args.log), "--vehicle", "revs_250lm", "--quiet",
           *(["--intersample", args.intersample] if args.intersample else [])]
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "est.json"
        commands = {"default (polished)": [*cli, "--json", str(out)], "--no-polish": [*cli, "--no-polish"]}
        _timed(commands["--no-polish"], env)  # warm-up: numba's cache
        times: dict[str, list[tuple[float, float]]] = {k: [] for k in commands}
        for _ in range(args.repeat):
            for name, cmd in commands.items():
                times[name].append(_timed(cmd, env))
        polish = json.loads(out.read_text()).get("polish", {})
    print(f"race log: {args.log.name}, {args.repeat} pairs, one command after the other"
          + (f", --intersample {args.intersample}" if args.intersample else ""))
    for name, runs in times.items():
        print(f"  {name:20s} wall median {statistics.median(w for w, _ in runs):6.2f} s"
              f"  CPU median {statistics.median(c for _, c in runs):6.2f} s")
    ratios = [a[0] / b[0] for a, b in zip(times["default (polished)"], times["--no-polish"])]
    cpu = [a[1] / b[1] for a, b in zip(times["default (polished)"], times["--no-polish"])]
    ratio = statistics.median(ratios)
    print(f"  default / --no-polish: wall {ratio:.2f}x (pairs {', '.join(f'{r:.2f}' for r in ratios)}),"
          f" CPU {statistics.median(cpu):.2f}x; target <= {TARGET:g}x: {'met' if ratio <= TARGET else 'NOT met'}")
    print(f"  polish: {polish.get('error', 'polished')} (its wall {polish.get('wall_s', float('nan')):.2f} s)")


if __name__ == "__main__":
    main()
