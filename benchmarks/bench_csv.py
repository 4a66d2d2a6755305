"""Read time and peak memory of the track-run CSV reader: the row-by-row reader against the numpy one.

Run: python benchmarks/bench_csv.py [--repeat N] [LOG ...]
Without LOG it writes the built-in 60 s, 1 kHz run (60,000 rows) to a temporary file. Both readers
read the same files in the same run (the machine is shared, so compare the ratio, not the times):
best of N wall times, and the peak of Python's allocations during one read (tracemalloc, which
numpy reports its arrays to).
"""

from __future__ import annotations

import argparse
import tempfile
import time
import tracemalloc
from pathlib import Path

import _checkout  # noqa: F401 -- this checkout's online_id, not an installed copy
import numpy as np

from online_id.io.tracklog import read_track_run, read_track_run_rowwise, write_track_run
from online_id.sim.simulator import simulate
from online_id.vehicle import load_vehicle

READERS = {"row by row (old)": read_track_run_rowwise, "numpy (new)": read_track_run}


def measure(reader, path: Path, repeat: int) -> tuple[float, float]:
    """(best wall time [s], peak traced memory [bytes]) of reading ``path``."""
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        reader(path)
        best = min(best, time.perf_counter() - t0)
    tracemalloc.start()
    reader(path)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return best, peak


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("logs", nargs="*", type=Path)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        logs = list(args.logs)
        if not logs:
            car = load_vehicle("haro2008")
            logs = [write_track_run(simulate(car, car.truth("track"), seed=0).run, Path(tmp) / "builtin.csv")]
        for path in logs:
            runs = {label: reader(path) for label, reader in READERS.items()}
            first, *others = runs.values()
            same = all(np.array_equal(getattr(first, c), getattr(o, c)) for o in others for c in first.channels)
            print(f"{path} ({len(first)} rows, {path.stat().st_size / 1e6:.1f} MB;"
                  f" both readers give {'the same' if same else 'DIFFERENT'} numbers):")
            results = {label: measure(reader, path, args.repeat) for label, reader in READERS.items()}
            for label, (t, peak) in results.items():
                print(f"  {label:<18} {t * 1e3:8.1f} ms  peak {peak / 1e6:6.1f} MB")
            (t_old, m_old), (t_new, m_new) = results.values()
            print(f"  new/old: time {t_new / t_old:.3f}x, memory {m_new / m_old:.3f}x")


if __name__ == "__main__":
    main()
