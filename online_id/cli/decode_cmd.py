"""``online-id decode``: a CAN or MDF log to the track-run table (CSV or parquet)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from online_id.cli.common import add_resample_argument, add_source_arguments, source_options
from online_id.cli.outputs import Outputs
from online_id.errors import OnlineIdError

#: Output formats by suffix.
OUT_SUFFIXES = (".csv", ".parquet")
#: A log whose first sample time is at least this [s] (a bus clock: the RAV4 log starts at 46,408 s) is
#: written with time from its first sample: the track-run CSV keeps 10 significant digits, which at
#: 46,408 s is 10 µs, 1 % of a 1 kHz period; from the start it is sub-µs for runs under an hour.
TIME_FROM_START_ABOVE_S = 1000.0


def add_parser(sub) -> None:
    p = sub.add_parser(
        "decode",
        description="Decode LOG (a CAN log in any format python-can reads, through --dbc and --signals; or an MDF"
        " file of decoded signals) into the track-run columns, with the checks the estimator uses: values older"
        " than the map's stale_after_s or from another counter are never used; a sample lacking yaw rate or"
        " lateral acceleration is dropped (counted), and a roll channel present in under 99 % of the samples"
        " is left out. Writes CSV or parquet by the suffix of --out.",
    )
    p.add_argument("log", type=Path, metavar="LOG", help="CAN log (.log, .asc, .blf, .trc, .mf4, ...) or MDF file")
    add_source_arguments(p)
    add_resample_argument(p)
    p.add_argument("--out", type=Path, required=True, metavar="RUN.csv|RUN.parquet", help="the track-run table")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from online_id.drivers.sources import load_run

    if args.out.suffix.lower() not in OUT_SUFFIXES:
        raise OnlineIdError(f"--out {args.out}: write {' or '.join(OUT_SUFFIXES)}")
    Outputs.check({"--out": args.out}, {"LOG": args.log})  # folder there and writable, not the input
    loaded = load_run(args.log, **source_options(args))
    run_ = loaded.run
    if args.resample:
        from online_id.drivers.resample import resample_run

        run_, info = resample_run(run_, args.resample)
        print(f"resampled {info['samples_before']} samples to {info['samples']} at {args.resample:g} Hz (longest"
              f" interval interpolated {1e3 * info['longest_interval_s']:.3g} ms)")
    t0 = float(run_.time[0])
    if abs(t0) >= TIME_FROM_START_ABOVE_S:  # bus seconds: 10 digits would keep only 10 µs of them
        run_.time = run_.time - t0
        print(f"time is in seconds from the first sample (log time {t0:.6f} s)")
    from online_id.io.tracklog import write_track_run

    outputs = Outputs(announce=False)  # atomic: a failed write leaves an earlier file as it was
    if not outputs.write_with(args.out, (lambda tmp: write_parquet(run_, tmp)) if args.out.suffix.lower() == ".parquet"
                              else (lambda tmp: write_track_run(run_, tmp))):
        return outputs.status()
    d = loaded.decode
    kept = f"{d.kept} of {d.samples} samples" if d is not None else f"{len(run_)} samples"
    span = float(run_.time[-1] - run_.time[0])
    print(f"wrote {args.out}: {kept}, {span:.2f} s, columns {', '.join(run_.channels)}")
    for line in loaded.problems():
        print(f"online-id: warning: {args.log}: {line}", file=sys.stderr)
    return 0


def write_parquet(run_, path: Path) -> None:
    """The run's columns as a parquet table (pandas with pyarrow)."""
    import pandas as pd

    df = pd.DataFrame({c: getattr(run_, c) for c in run_.channels})
    try:
        df.to_parquet(path, index=False)
    except (OSError, ImportError, ValueError) as exc:
        raise OnlineIdError(f"{path}: cannot write parquet: {exc}") from None
