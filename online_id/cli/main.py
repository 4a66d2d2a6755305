"""Entry point of the ``online-id`` command.

Each sub-command lives in its own module with ``add_parser(subparsers)`` and
``run(args) -> int``, named in :data:`COMMANDS` with its line of ``--help`` and imported only when it runs.
Errors meant for the user (:class:`OnlineIdError`) become one line on stderr and exit status 2, never a
traceback; any other exception is an internal error: one line naming the stage it came from and a crash
report, what was computed before it written, exit status 70 (:mod:`online_id.cli.crash`).
"""

from __future__ import annotations

import argparse
import importlib
import sys
from pathlib import Path

from online_id import __version__
from online_id.cli import crash, library_warnings, termination
from online_id.errors import OnlineIdError
from online_id.util import first_compile, stages
from online_id.util.interrupts import interrupt_inside
from online_id.util.threads import single_blas_thread

#: Each sub-command: its name, its module (imported only when the command is chosen, or a parser's tree is
#: walked: a command pays for its own imports, not the others', issue 26) and its line in ``--help``.
COMMANDS = (
    ("estimate", "estimate_cmd", "estimate the 8 parameters online from a track-run log"),
    ("fit", "fit_cmd", "batch fit of the 8 parameters (hybrid GA with Simplex recombination, Haro 2008)"),
    ("simulate", "simulate_cmd", "simulate a test run and write it as a track-run CSV"),
    ("replay", "replay_cmd", "play a track-run CSV or a CAN log onto a CAN bus at real-time rate"),
    ("listen", "listen_cmd", "estimate the parameters live from a CAN bus"),
    ("plot", "plot_cmd", "draw figures"),
    ("diagnose", "diagnose_cmd", "find the sim-to-real gap and the unmodelled effect that explains it"),
    ("decode", "decode_cmd", "decode a CAN or MDF log into a track-run table"),
    ("check", "check_cmd",
     "what a run can tell: excitation, sampling, Cramér-Rao bound, and what manoeuvre is missing"),
    ("batch", "batch_cmd", "estimate many logs at once on a Dask cluster; a summary row and a JSON per log"),
    ("report", "report_cmd", "one HTML page of a run: check, estimate, fit, diagnosis, excitation meter"),
)


class _CommandParsers(dict):
    """The sub-parsers action's name → parser map, each parser built by its module's ``add_parser`` when it
    is first looked up (argparse's ``parser_name`` lookup, or walking ``choices``' values or items).

    The keys are there from the start: ``--help`` lists each command from :data:`COMMANDS` and argparse
    checks a command's name against them, without importing any command's module."""

    def __init__(self, action: argparse._SubParsersAction):
        super().__init__()
        self._action = action
        self._modules: dict[str, str] = {}

    def declare(self, name: str, module: str) -> None:
        self._modules[name] = module
        dict.__setitem__(self, name, None)

    def _load(self, name: str) -> None:
        module = self._modules.pop(name, None)
        if module is not None:
            importlib.import_module(f"online_id.cli.{module}").add_parser(self)

    def add_parser(self, name: str, **kwargs) -> argparse.ArgumentParser:
        """As ``_SubParsersAction.add_parser`` for a declared command: the module's description, options and
        defaults; its line in the listing is :data:`COMMANDS`'."""
        if name not in self or dict.__getitem__(self, name) is not None:
            raise ValueError(f"sub-command {name!r} is not declared in COMMANDS, or built twice")
        kwargs.setdefault("prog", f"{self._action._prog_prefix} {name}")
        parser = self._action._parser_class(**kwargs)
        dict.__setitem__(self, name, parser)
        return parser

    def __getitem__(self, name: str) -> argparse.ArgumentParser:
        self._load(name)
        return dict.__getitem__(self, name)

    def get(self, name, default=None):
        return self[name] if name in self else default

    def values(self):
        for name in list(self._modules):
            self._load(name)
        return dict.values(self)

    def items(self):
        self.values()
        return dict.items(self)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="online-id",
        description="Identify a car's lateral-dynamics parameters (Mzz, Mxx, D1, D2, Aro, Kro, b1, b2).",
    )
    parser.add_argument("--version", action="version", version=f"online-id {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    sub._name_parser_map = sub.choices = parsers = _CommandParsers(sub)
    for name, module, line in COMMANDS:
        parsers.declare(name, module)
        sub._choices_actions.append(sub._ChoicesPseudoAction(name, (), line))
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


def _note_compiling(line: str) -> None:
    """The one line that a one-time compile is starting (online_id/util/jit.py), on stderr; above a progress
    bar when one is drawn."""
    text = f"online-id: note: {line}"
    tqdm = sys.modules.get("tqdm")
    if tqdm is not None and hasattr(tqdm, "tqdm"):
        tqdm.tqdm.write(text, file=sys.stderr)
    else:
        print(text, file=sys.stderr, flush=True)


@single_blas_thread
def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)  # as typed: the verdict's next steps extend it
    # a first run after installing waits for numba's compile: one line says so (not under --quiet)
    first_compile.listen(None if getattr(args, "quiet", False) else _note_compiling)
    with stages.session() as session:  # what the command keeps, and the failures its stages carried on from
        try:
            check_log_arguments(args)  # a directory or a device as LOG: one line, before anything runs
            # SIGTERM and SIGHUP end a run as Ctrl-C does; library warnings become one line each
            with termination.signals_interrupt(), library_warnings.reported_warnings():
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
            print(f"online-id: interrupted ({termination.signal_name()}) before any result", file=sys.stderr)
            return termination.exit_status()
        except Exception as exc:  # noqa: BLE001 - no input may end in a traceback: name the stage, keep the results
            return crash.internal_error(exc, args, argv, session)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
