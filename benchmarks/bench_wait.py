"""Where a user waits (issue 40): each row of the issue's table measured in one run, against its target.

Run: python benchmarks/bench_wait.py [--rows diagnose,validate,carry,report,ukf,first,tyres,filter]
                                     [--baseline DIR] [--repeat 1]

Rows (the race log is ``../shared/realdata/revs_250lm/revs_250lm_laps_0-400s.csv``; each command a fresh process
of this checkout, start-up included, its wall time the figure; ``--repeat`` runs, the median):

* ``diagnose``: ``online-id diagnose RACE --vehicle revs_250lm`` (README tour step 4), target ≤ 60 s;
* ``validate``: the same with ``--validate`` on a later stretch (the log cut at 300 s into two CSVs, fitted on
  0-300 s, judged on 300-400 s), target ≤ 60 s;
* ``carry``: ``online-id estimate RACE --vehicle revs_250lm --effect tire_saturation_axles:1.06387:1.27173`` (what
  README tour step 5's ``--effects-from`` carried when issue 40 was filed: a μ per axle; kept so that the figures
  compare; since 2026-11-28 step 5 carries ``load_sensitivity`` and a steering offset), target ≤ 10 s;
* ``report``: ``online-id report RACE --vehicle revs_250lm --out RUN.html``, target ≤ 90 s;
* ``ukf``: ``online-id estimate RACE --vehicle revs_250lm --filter ukf``, target ≤ 5 s;
* ``first``: the README's main command (``online-id estimate``) the first time after ``pip install .`` into a fresh
  venv against a warm run (benchmarks/bench_first_run.py), target ≤ 2× (first ÷ warm);
* ``tyres``: the EKF with the saturating tyre per sample against the linear EKF on the same 60 s, 1 kHz run at
  0.9 g (benchmarks/bench_tyres.py's run), target ≤ 1.5×;
* ``filter``: the EKF filter alone (the array path, the built-in run) against a bare filterpy predict+update step
  (benchmarks/bench_fast.py), target ≤ 0.5×.

``--baseline DIR`` (a checkout with its own ``.venv``, e.g. the main the issue measured) runs the command rows by
that checkout too, interleaved with this one's, and prints the ratio (this ÷ baseline). Before the timing, each
command row runs once untimed on the log's first 20 s by each checkout, so that no timed run compiles. The
issue's own figures ("today" when it was filed, on the same kind of machine) are printed beside them. No test
depends on these times.
"""

from __future__ import annotations

import argparse
import csv
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import _checkout

ROOT = Path(_checkout.ROOT)
RACE = (ROOT / ".." / "shared" / "realdata" / "revs_250lm" / "revs_250lm_laps_0-400s.csv").resolve()
CARRIED = "tire_saturation_axles:1.06387:1.27173"
SPLIT_S = 300.0
#: Seconds of the log the warm-up's commands take (:func:`warm_up`).
WARM_S = 20.0

#: row: (what, target, unit, the issue's "today")
ROWS = {
    "diagnose": ("diagnose of the race log (README step 4)", 60.0, "s", "347-851 s"),
    "validate": ("diagnose --validate on a later stretch (0-300 s, judged on 300-400 s)", 60.0, "s", "198 s"),
    "carry": ("estimate carrying the race log's μ per axle (README step 5)", 10.0, "s", "106 s"),
    "report": ("report of the race log", 90.0, "s", "376 s"),
    "ukf": ("estimate --filter ukf of the race log", 5.0, "s", "13.3 s"),
    "first": ("README main command, first run after install ÷ warm", 2.0, "x", "14.4 s / 2.1 s"),
    "tyres": ("EKF with the saturating tyre ÷ the linear EKF, per sample", 1.5, "x", "1.3-3.4x"),
    "filter": ("EKF filter alone ÷ a bare filterpy predict+update step", 0.5, "x", "0.93x"),
}


def split(log: Path, tmp: Path) -> tuple[Path, Path]:
    """``log`` cut at SPLIT_S into two CSVs (the header on both); a log that ends before SPLIT_S, at its middle."""
    first, second = tmp / f"{log.stem}_train.csv", tmp / f"{log.stem}_held.csv"
    with open(log, newline="") as f:
        rows = list(csv.reader(f))
    header, body = rows[0], rows[1:]
    column = header.index("time")
    times = [float(r[column]) for r in body]
    cut = SPLIT_S if times[-1] > SPLIT_S else 0.5 * (times[0] + times[-1])
    for path, part in ((first, [r for r, t in zip(body, times) if t < cut]),
                       (second, [r for r, t in zip(body, times) if t >= cut])):
        with open(path, "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(header)
            w.writerows(part)
    return first, second


def warm_up(checkout: Path, cli: dict[str, list[str]]) -> None:
    """Each command row once on the log's first WARM_S seconds, untimed: the compiled code each needs is then in the
    checkout's cache (a first run compiles; bench_first_run.py times that), as for a user's second command."""
    for args in cli.values():
        run_cli(checkout, args, check=False)


def head(log: Path, tmp: Path, seconds: float = WARM_S) -> Path:
    """The first ``seconds`` of ``log`` as a CSV (what the warm-up runs)."""
    out = tmp / "race_head.csv"
    with open(log, newline="") as f, open(out, "w", newline="") as a:
        rows = csv.reader(f)
        header = next(rows)
        column = header.index("time")
        w = csv.writer(a)
        w.writerow(header)
        t0 = None
        for row in rows:
            t = float(row[column])
            t0 = t if t0 is None else t0
            if t - t0 >= seconds:
                break
            w.writerow(row)
    return out


def commands(tmp: Path, log: Path = RACE) -> dict[str, list[str]]:
    """The CLI rows' arguments (after ``online-id``) on ``log`` (its split at SPLIT_S for ``validate``; a log shorter
    than that: its two halves)."""
    train, held = split(log, tmp)
    car = ["--vehicle", "revs_250lm"]
    return {
        "diagnose": ["diagnose", str(RACE), *car, "--quiet", "--json", str(tmp / "diag.json")],
        "validate": ["diagnose", str(train), "--validate", str(held), *car, "--quiet", "--json", str(tmp / "v.json")],
        "carry": ["estimate", str(RACE), *car, "--effect", CARRIED, "--quiet", "--json", str(tmp / "carry.json")],
        "report": ["report", str(RACE), *car, "--quiet", "--out", str(tmp / "race.html")],
        "ukf": ["estimate", str(RACE), *car, "--filter", "ukf", "--quiet", "--json", str(tmp / "ukf.json")],
    }


def run_cli(checkout: Path, args: list[str], check: bool = True) -> float:
    """Wall time [s] of ``online-id ARGS`` by ``checkout`` (this one: this interpreter; another: its .venv)."""
    python = sys.executable if checkout == ROOT else str(checkout / ".venv" / "bin" / "python")
    env = dict(os.environ, PYTHONPATH=str(checkout))
    t0 = time.perf_counter()
    done = subprocess.run([python, "-m", "online_id.cli.main", *args], env=env, cwd=checkout,
                          stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    wall = time.perf_counter() - t0
    if check and done.returncode not in (0, 1):  # 1: a verdict that is not consistent (the race car's); a full run
        raise SystemExit(f"{checkout}: online-id {' '.join(args)} failed ({done.returncode}): "
                         f"{done.stderr.strip().splitlines()[-1:]}")
    return wall


def first_run() -> float:
    """first ÷ warm of the README's main command after a fresh install (bench_first_run's procedure, once)."""
    from _timing import timed
    from bench_first_run import forget_compiled, install
    env = {k: v for k, v in os.environ.items() if not k.startswith(("NUMBA_", "PYTHON", "VIRTUAL_ENV"))}
    env.update(OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    with tempfile.TemporaryDirectory() as name:
        tmp = Path(name)
        bin_dir, package = install(ROOT, tmp)
        run_env = dict(env, XDG_CACHE_HOME=str(tmp / "cache"))
        forget_compiled(package)
        first, _ = timed([str(bin_dir / "online-id"), "estimate"], run_env, tmp)
        warm, _ = timed([str(bin_dir / "online-id"), "estimate"], run_env, tmp)
    print(f"  first run {first:.2f} s, warm {warm:.2f} s", flush=True)
    return first / warm


def tyres_ratio() -> float:
    """The EKF with the saturating tyre ÷ the linear EKF, per sample, on bench_tyres.py's 0.9 g run (best of 3)."""
    import numpy as np
    from bench_tyres import best_of

    from online_id.effects import parse_effect, parse_effect_to_estimate
    from online_id.estimation import make_estimator, run_estimator
    from online_id.sim.simulator import simulate
    from online_id.stream.samples import SampleArrays
    from online_id.vehicle import load_vehicle
    car = load_vehicle("haro2008")
    run = simulate(car, car.truth("track"), amplitude_rad=np.deg2rad(60),
                   effects=[parse_effect("tire_saturation=0.8")], seed=3).run
    arrays = SampleArrays.from_run(run)
    tyre = [parse_effect_to_estimate("tire_saturation")]
    short = SampleArrays.from_run(simulate(car, car.truth("track"), duration_s=0.5).run)
    run_estimator(make_estimator(car, "ekf", effects=tyre), short)  # compiled outside the timing
    run_estimator(make_estimator(car, "ekf"), short)
    lin, _ = best_of(3, lambda: run_estimator(make_estimator(car, "ekf"), arrays))
    tyr, _ = best_of(3, lambda: run_estimator(make_estimator(car, "ekf", effects=tyre), arrays))
    print(f"  linear {1e6 * lin / len(arrays):.1f} µs/sample, with tyres {1e6 * tyr / len(arrays):.1f} µs/sample",
          flush=True)
    return tyr / lin


def filter_ratio() -> float:
    """The EKF filter alone over the built-in run's arrays ÷ the bare filterpy step (medians of 3)."""
    from bench_fast import N, bare, filter_only

    from online_id.sim.simulator import simulate
    from online_id.stream.samples import SampleArrays
    from online_id.vehicle import load_vehicle
    car = load_vehicle("haro2008")
    arrays = SampleArrays.from_run(simulate(car, car.truth("track"), seed=0).run)
    assert len(arrays) == N
    filter_only(car, "ekf", SampleArrays.from_run(simulate(car, car.truth("track"), duration_s=0.5).run))
    ours, theirs = [], []
    for _ in range(3):
        theirs.append(bare(N)[0])
        ours.append(filter_only(car, "ekf", arrays)[0])
    print(f"  EKF {statistics.median(ours):.1f} µs/sample, bare filterpy {statistics.median(theirs):.1f} µs/sample",
          flush=True)
    return statistics.median(ours) / statistics.median(theirs)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", default=",".join(ROWS), help=f"comma-separated rows (default all: {','.join(ROWS)})")
    ap.add_argument("--baseline", type=Path, metavar="DIR", help="a checkout with .venv to run the command rows by too")
    ap.add_argument("--repeat", type=int, default=1)
    args = ap.parse_args()
    rows = args.rows.split(",")
    unknown = [r for r in rows if r not in ROWS]
    if unknown:
        ap.error(f"unknown row(s) {', '.join(unknown)}; the rows: {', '.join(ROWS)}")
    if not RACE.is_file():
        raise SystemExit(f"the race log is not at {RACE}")
    results: dict[str, tuple[float, float | None]] = {}
    with tempfile.TemporaryDirectory() as name:
        tmp = Path(name)
        cli = commands(tmp)
        warm = {r: a for r, a in commands(tmp, head(RACE, tmp)).items() if r in rows}
        if warm:
            print(f"warming up: the command rows on the log's first {WARM_S:g} s, untimed ...", flush=True)
            for checkout in [ROOT, *([args.baseline.resolve()] if args.baseline else [])]:
                warm_up(checkout, warm)
        for row in rows:
            what, target, unit, today = ROWS[row]
            print(f"{row}: {what} ...", flush=True)
            if row in cli:
                ours, base = [], []
                for _ in range(max(1, args.repeat)):
                    ours.append(run_cli(ROOT, cli[row]))
                    if args.baseline:
                        base.append(run_cli(args.baseline.resolve(), cli[row]))
                    print(f"  {ours[-1]:.1f} s" + (f", baseline {base[-1]:.1f} s" if base else ""), flush=True)
                results[row] = statistics.median(ours), statistics.median(base) if base else None
            else:
                results[row] = {"first": first_run, "tyres": tyres_ratio, "filter": filter_ratio}[row](), None
    print(f"\n{'row':<9} {'measured':>10} {'target':>8}  {'':<7} {'baseline':>10} {'ratio':>6}  the issue's today")
    for row, (value, base) in results.items():
        what, target, unit, today = ROWS[row]
        fig = f"{value:.1f} s" if unit == "s" else f"{value:.2f}x"
        tgt = f"≤ {target:g} {unit}" if unit == "s" else f"≤ {target:g}x"
        met = "met" if value <= target else "MISSED"
        b = f"{base:>8.1f} s {value / base:>5.2f}x" if base else f"{'':>10} {'':>6}"
        print(f"{row:<9} {fig:>10} {tgt:>8}  {met:<7} {b}  {today}")
    print(f"(the race log: {RACE}; medians of {args.repeat}; commands in a fresh process each, start-up included)")


if __name__ == "__main__":
    main()
