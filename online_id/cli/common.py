"""Pieces several sub-commands share: common flags, and printing a workflow's messages."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from online_id.stream.samples import MEASURED_CHANNELS

#: LOG's help in every command that reads one log and runs on the built-in run without it.
LOG_HELP = "track-run CSV or parquet, CAN log or MDF file (default: built-in run)"


def log_parent() -> argparse.ArgumentParser:
    """The flags of every command that reads one LOG (check, fit, plot convergence, diagnose, report), for
    argparse's ``parents=``: LOG, --vehicle, LOG's reading (:func:`add_source_arguments`) and --resample, one
    help text each. ``estimate`` (whose source flags ``batch`` shares) adds the same with the same functions."""
    p = argparse.ArgumentParser(add_help=False)
    p.add_argument("log", nargs="?", type=Path, metavar="LOG", help=LOG_HELP)
    add_vehicle_argument(p)
    add_source_arguments(p)
    add_resample_argument(p)
    return p


def add_vehicle_argument(p) -> None:
    p.add_argument("--vehicle", default=None,
                   help="built-in vehicle name or TOML file (default: haro2008, Haro's test car; said in a warning"
                   " for a log it did not make)")


def add_filter_argument(p) -> None:
    """``--filter``: its choices are the registry's names (:data:`online_id.filters.FILTERS`, read when the parser
    is built; importing the registry imports no filter)."""
    from online_id.filters.registry import FILTERS

    default = next(iter(FILTERS))
    p.add_argument("--filter", choices=tuple(FILTERS), default=default, help=f"online filter (default: {default})")


def add_filter_arguments(p) -> None:
    add_filter_argument(p)
    p.add_argument("--prior", type=Path, metavar="FIT.json",
                   help="start from a fit's (or an earlier estimate's) values and standard deviations")
    p.add_argument("--channels", metavar="LIST",
                   help="comma-separated measured channels to use"
                   f" (default: all present of {','.join(MEASURED_CHANNELS)})")
    p.add_argument("--correct-every", type=int, metavar="K",
                   help="correct every K-th sample with the block means of the K samples (default: 20; a block"
                   " never spans more than 50 ms with the EKF, 20 ms with the UKF, FilterConfig.max_block_s:"
                   " 5 and 2 samples at 100 Hz, 1 at 25 Hz)")
    add_intersample_argument(p)


def add_intersample_argument(p) -> None:
    """``--intersample``: the steering between samples every model of the job takes (the filter, the polish, the
    fit, the diagnosis, the checks: the workflows' ``intersample`` keyword)."""
    from online_id.model.intersample import INTERSAMPLE

    p.add_argument("--intersample", choices=INTERSAMPLE, default=None,
                   help="the steering angle between two samples: hold (held until the next, as before issue 36;"
                   " lags by half a sample), linear (the straight line to the next), cubic (the curve through the"
                   " samples around it, as a logger samples a continuous car; a live filter works one sample late)"
                   "; default: the filter's, FilterConfig.intersample")


def add_source_arguments(p) -> None:
    """LOG's reading: --dbc/--signals for CAN and MDF logs (and a column map for a table), --can-channel,
    --drop-nan (drivers/sources.py reads them)."""
    from online_id.cli.bus_args import add_dbc_arguments

    add_dbc_arguments(p)
    p.add_argument("--can-channel", metavar="CH",
                   help="CAN channel of a log to use: can0, can1, ... (or a number, counted from 0; 'any' for"
                   " all; default: the signal map's, else all)")
    p.add_argument("--drop-nan", action="store_true",
                   help="a CSV or Parquet table: drop the rows with NaN, inf or an empty cell in a column used"
                   " (counted and said) instead of refusing the file at the first")


def add_resample_argument(p) -> None:
    p.add_argument("--resample", type=float, metavar="HZ",
                   help="put a decoded log on an even grid at HZ by linear interpolation (a CAN log's trigger frames"
                   " arrive unevenly; the fit and the diagnosis need one step); refuses across dropouts over 0.1 s")


def source_options(args) -> dict:
    """Keywords for online_id.drivers.sources.open_source/load_run from the flags of add_source_arguments."""
    return {"dbc": getattr(args, "dbc", None), "signals": getattr(args, "signals", None),
            "can_channel": getattr(args, "can_channel", None), "drop_nan": bool(getattr(args, "drop_nan", False))}


def printed_messages(defer: tuple[str, ...] = ()):
    """A :class:`~online_id.workflows.messages.Messages` that prints each line where the command always
    printed it: ``status`` lines on stderr as they are, ``note`` and ``warning`` on stderr as
    ``online-id: note:`` / ``online-id: warning:``, ``result`` lines on stdout. Lines of the kinds in
    ``defer`` are held until :func:`print_deferred` (after the results, so an input error stays the
    only line and the notes sit beside the table they explain)."""
    from online_id.workflows.messages import Messages

    def echo(kind: str, line: str) -> None:
        if kind not in defer:
            _print(kind, line)

    messages = Messages(echo=echo)
    messages.held = tuple(defer)
    return messages


def print_deferred(messages) -> None:
    """Print the lines ``printed_messages(defer=...)`` held, in order."""
    for kind, line in messages.lines:
        if kind in messages.held:
            _print(kind, line)


def _print(kind: str, line: str) -> None:
    if kind == "result":
        print(line, flush=True)
    elif kind in ("note", "warning"):
        print(f"online-id: {kind}: {line}", file=sys.stderr, flush=True)
    else:
        print(line, file=sys.stderr, flush=True)
