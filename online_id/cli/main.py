"""Entry point of the ``online-id`` command.

Each sub-command lives in its own module with ``add_parser(subparsers)`` and
``run(args) -> int``.  Errors meant for the user (:class:`OnlineIdError`)
become one line on stderr and exit status 2, never a traceback; any other exception is an internal
error: one line naming the stage it came from and a crash report, what was computed before it
written, exit status 70 (:mod:`online_id.cli.crash`).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from online_id import __version__
from online_id.cli import (
    batch_cmd,
    check_cmd,
    crash,
    decode_cmd,
    diagnose_cmd,
    estimate_cmd,
    fit_cmd,
    library_warnings,
    listen_cmd,
    plot_cmd,
    replay_cmd,
    report_cmd,
    signals,
    simulate_cmd,
)
from online_id.errors import OnlineIdError
from online_id.util import stages
from online_id.util.interrupts import interrupt_inside
from online_id.util.threads import single_blas_thread

COMMANDS = (estimate_cmd, fit_cmd, simulate_cmd, replay_cmd, listen_cmd, plot_cmd, diagnose_cmd, decode_cmd,
            check_cmd, batch_cmd, report_cmd)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="online-id",
        description="Identify a car's lateral-dynamics parameters (Mzz, Mxx, D1, D2, Aro, Kro, b1, b2).",
    )
    parser.add_argument("--version", action="version", version=f"online-id {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for module in COMMANDS:
        module.add_parser(sub)
    return parser


def check_log_arguments(args) -> None:
    """Every log a command reads (LOG, diagnose's --validate) names a file that exists; batch's LOG... are
    files where they exist (a missing one is a failed row of the batch, as any log it cannot read)."""
    from online_id.io.tracklog import check_log_path

    for what, attr in (("LOG", "log"), ("LOG", "logs"), ("--validate", "validate")):
        value = getattr(args, attr, None)
        for path in (value if isinstance(value, list) else [value] if value is not None else []):
            if attr != "logs" or Path(path).exists():
                check_log_path(path, what)


@single_blas_thread
def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)  # as typed: the verdict's next steps extend it
    with stages.session() as session:  # what the command keeps, and the failures its stages carried on from
        try:
            check_log_arguments(args)  # a directory or a device as LOG: one line, before anything runs
            # SIGTERM and SIGHUP end a run as Ctrl-C does; library warnings become one line each
            with signals.signals_interrupt(), library_warnings.reported_warnings():
                status = int(args.run(args) or 0)
            crash.report_absorbed(args, argv, session)
            return status
        except OnlineIdError as exc:
            for line in session.flush(stages.Failure(stages.stage_of(exc, args.command), str(exc))):
                print(f"online-id: error: {line}", file=sys.stderr)  # what was computed before it is written
            crash.report_absorbed(args, argv, session)
            print(f"online-id: error: {exc}", file=sys.stderr)
            return 2
        except (KeyboardInterrupt, SystemError) as exc:  # before any result existed (commands keep what they reached)
            if interrupt_inside(exc) is None:  # a SystemError not from a signal in compiled code: a bug
                return crash.internal_error(exc, args, argv, session)
            print(f"online-id: interrupted ({signals.signal_name()}) before any result", file=sys.stderr)
            return signals.exit_status()
        except Exception as exc:  # noqa: BLE001 - no input may end in a traceback: name the stage, keep the results
            return crash.internal_error(exc, args, argv, session)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
