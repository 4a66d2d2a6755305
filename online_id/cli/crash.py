"""An unexpected failure as one line, a crash report file and a documented exit status, never a traceback.

Errors meant for the user (:class:`~online_id.errors.OnlineIdError`) are one line and exit status 2. Anything
else is a bug of online-id's (or of a library it calls, met with inputs nobody tried): the top level
(:mod:`online_id.cli.main`) hands it to :func:`internal_error`, which

1. writes a crash report (the command line, the versions of online-id and its numerical libraries, the
   traceback, each input file's name and size) beside the outputs (the folder of ``--json``/``--out``/...)
   or, without one that can be written, in the temporary folder;
2. writes what the command had computed before the failure (registered with
   :func:`online_id.util.stages.keep`), marked with the stage that failed;
3. prints ``online-id: internal error in <stage>: <message>; please report with <crash file>`` and returns
   :data:`EXIT_INTERNAL_ERROR`.

:func:`report_absorbed` does the same for failures a stage caught and carried on from
(:func:`online_id.util.stages.absorb`): the results stand, one warning line names the report.
"""

from __future__ import annotations

import datetime as _dt
import os
import platform
import shlex
import sys
import tempfile
import traceback
from pathlib import Path

from online_id.util.stages import Absorbed, Failure, Session, describe, stage_of

#: Exit status of an internal error (BSD sysexits' EX_SOFTWARE): not 1 (``batch``, ``listen`` and ``replay``
#: use 1 for a failed log or a lost bus), 2 (input), 3 (--strict), 4 (a failed write) or 128 + a signal.
EXIT_INTERNAL_ERROR = 70
#: The distributions whose versions a crash report lists.
VERSIONS_OF = ("online-id", "numpy", "scipy", "filterpy", "numba", "pandas", "python-can", "cantools", "asammdf")
#: Attributes of a command's arguments that are outputs (a crash report goes into the first one's folder).
OUTPUT_ATTRIBUTES = ("json", "out", "report", "trace", "plot")


def internal_error(exc: BaseException, args, argv: list[str] | None, session: Session | None) -> int:
    """Report ``exc`` (see the module docstring); returns :data:`EXIT_INTERNAL_ERROR`."""
    where = stage_of(exc, getattr(args, "command", None) or "online-id")
    absorbed = session.absorbed if session is not None else []
    try:
        report = write_crash_report(args, argv, [Absorbed(where, describe(exc), _traceback(exc)), *absorbed])
    except Exception:  # noqa: BLE001 - the report is a courtesy: the one line must come out whatever happens
        report = None
    failure = Failure(stage=where, error=describe(exc), crash_report=str(report) if report else None)
    problems = session.flush(failure) if session is not None else []
    for line in problems:
        print(f"online-id: error: {line}", file=sys.stderr)
    tail = f"; please report with {report}" if report else "; please report it (no crash report could be written)"
    print(f"online-id: internal error in {where}: {describe(exc)}{tail}", file=sys.stderr, flush=True)
    return EXIT_INTERNAL_ERROR


def report_absorbed(args, argv: list[str] | None, session: Session) -> None:
    """One warning line per failure a stage carried on from, naming a crash report with their tracebacks."""
    if not session.absorbed:
        return
    try:
        report = write_crash_report(args, argv, session.absorbed)
    except Exception:  # noqa: BLE001 - as in internal_error
        report = None
    tail = f"; please report with {report}" if report else ""
    for a in session.absorbed:
        print(f"online-id: warning: internal error in {a.stage}: {a.error}; the results above stand without it"
              f"{tail}", file=sys.stderr, flush=True)


def _traceback(exc: BaseException) -> str:
    return "".join(traceback.format_exception(exc))


def write_crash_report(args, argv: list[str] | None, failures: list[Absorbed]) -> Path | None:
    """The crash report file (see the module docstring), or None when no folder took it."""
    text = crash_report_text(args, argv, failures)
    stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    for folder in _report_folders(args):
        try:
            fd, name = tempfile.mkstemp(prefix=f"online-id-crash-{stamp}-", suffix=".txt", dir=folder)
            with os.fdopen(fd, "w", encoding="utf-8") as fh:
                fh.write(text)
            return Path(name)
        except OSError:
            continue
    return None


def _report_folders(args) -> list[Path]:
    """The outputs' folders (a report folder itself), then the temporary folder."""
    folders = []
    for attr in OUTPUT_ATTRIBUTES:
        value = getattr(args, attr, None)
        if isinstance(value, (str, Path)) and str(value):
            p = Path(value)
            folders.append(p if attr == "report" and p.is_dir() else p.parent)
    folders.append(Path(tempfile.gettempdir()))
    return [f for f in dict.fromkeys(folders) if f.is_dir()]


def crash_report_text(args, argv: list[str] | None, failures: list[Absorbed]) -> str:
    argv = list(sys.argv[1:] if argv is None else argv)
    lines = [
        "online-id crash report: please attach this file to an issue (it holds no data, only names and sizes)",
        f"time: {_dt.datetime.now().isoformat(timespec='seconds')}",
        f"command: online-id {shlex.join(str(a) for a in argv)}",
        f"working directory: {os.getcwd()}",
        f"python: {sys.version.split()[0]} ({platform.platform()})",
        "versions: " + ", ".join(f"{name} {_version(name)}" for name in VERSIONS_OF),
        "inputs:",
        *(f"  {flag} {path}: {size}" for flag, path, size in input_files(args)),
    ]
    for f in failures:
        lines += ["", f"stage: {f.stage}", f"error: {f.error}", "traceback:", f.traceback.rstrip()]
    return "\n".join(lines) + "\n"


def _version(name: str) -> str:
    from importlib import metadata  # (only a crash report asks: not at every start)

    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return "not installed"


def input_files(args) -> list[tuple[str, str, str]]:
    """(flag, path, size) of every file argument that is not an output."""
    out = []
    for attr, value in sorted(vars(args).items()) if args is not None else []:
        if attr in OUTPUT_ATTRIBUTES:
            continue
        for v in value if isinstance(value, (list, tuple)) else [value]:
            if not isinstance(v, (str, Path)) or not str(v):
                continue
            p = Path(v)
            try:
                if p.is_file():
                    out.append((attr, str(p), f"{p.stat().st_size:,} bytes"))
                elif p.is_dir() and attr in ("log", "logs"):
                    out.append((attr, str(p), "a directory"))
            except OSError as exc:
                out.append((attr, str(p), f"unreadable ({describe(exc)})"))
    return out
