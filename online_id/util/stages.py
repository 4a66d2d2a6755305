"""Which stage of a command a failure came from, and what was computed before it.

A command runs as stages: reading the log, the plausibility checks, the filter, the polish, the GA, a
diagnosis candidate, ... Three small tools keep a failure in one stage from losing the others' work:

- :class:`stage` (a context manager and decorator) tags an exception that escapes it with the stage's name
  (the innermost stage wins), so the one line the CLI prints names where it happened:
  ``online-id: internal error in polish: ...``.
- :func:`absorb` is for a stage whose failure must not end the command (the polish after the filter, one
  diagnosis candidate): the stage catches the exception itself, records it here (its traceback goes into
  the crash report the CLI writes at the end) and carries on with what it has, the failure named in its
  result (``polish.error``, a failed candidate).
- :func:`keep` registers, once something worth keeping exists (the filter's estimate), a function that
  writes it; when a later stage fails unexpectedly the CLI's top level calls it with the :class:`Failure`,
  so the output is written marked with the stage that failed.

:func:`session` scopes the last two to one command (the CLI opens one per call of ``main``); outside a
session :func:`absorb` and :func:`keep` only describe and do nothing else, so library use (the Python
API) behaves the same without a CLI around it.
"""

from __future__ import annotations

import contextvars
import traceback
from collections.abc import Callable, Iterator
from contextlib import ContextDecorator, contextmanager
from dataclasses import dataclass, field

#: The attribute an exception carries the name of the stage it escaped from in.
STAGE_ATTRIBUTE = "online_id_stage"
#: Longest message kept in a one-line description [characters].
MAX_MESSAGE_CHARS = 300


class stage(ContextDecorator):  # noqa: N801 - reads as a statement: ``with stage("polish"):``
    """Tag an exception escaping the block with ``name`` (unless an inner stage already did)."""

    def __init__(self, name: str):
        self.name = name

    def __enter__(self) -> stage:
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        if isinstance(exc, Exception) and getattr(exc, STAGE_ATTRIBUTE, None) is None:
            try:
                setattr(exc, STAGE_ATTRIBUTE, self.name)
            except (AttributeError, TypeError):  # an exception type with __slots__: it goes untagged
                pass
        return False


def stage_of(exc: BaseException, default: str | None = None) -> str | None:
    """The stage ``exc`` escaped from (see :class:`stage`), or ``default``."""
    return getattr(exc, STAGE_ATTRIBUTE, None) or default


def describe(exc: BaseException) -> str:
    """``exc`` as one line: its type and the first line of its message, cut at :data:`MAX_MESSAGE_CHARS`."""
    text = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
    if len(text) > MAX_MESSAGE_CHARS:
        text = text[:MAX_MESSAGE_CHARS - 1] + "…"
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


@dataclass(frozen=True)
class Failure:
    """An unexpected failure: the stage it came from, one line of what it was, and where its crash report
    went (None when none was written)."""

    stage: str
    error: str
    crash_report: str | None = None

    def to_json_dict(self) -> dict:
        return {"stage": self.stage, "error": self.error, "crash_report": self.crash_report}


@dataclass
class Absorbed:
    """A failure a stage caught and carried on from (see :func:`absorb`), with its traceback."""

    stage: str
    error: str
    traceback: str


@dataclass
class Session:
    """What one command registered: functions that write what was kept, failures absorbed."""

    kept: dict[str, Callable[[Failure], object]] = field(default_factory=dict)
    absorbed: list[Absorbed] = field(default_factory=list)

    def flush(self, failure: Failure) -> list[str]:
        """Call every kept writer with ``failure``, newest first; one line per writer that failed itself."""
        problems = []
        for what, write in reversed(list(self.kept.items())):
            try:
                write(failure)
            except Exception as exc:  # noqa: BLE001 - a broken writer must not hide the failure being reported
                problems.append(f"could not write {what}: {describe(exc)}")
        return problems


_session: contextvars.ContextVar[Session | None] = contextvars.ContextVar("online_id_stage_session", default=None)


@contextmanager
def session() -> Iterator[Session]:
    """One command's registry of kept results and absorbed failures."""
    current = Session()
    token = _session.set(current)
    try:
        yield current
    finally:
        _session.reset(token)


def keep(what: str, write: Callable[[Failure], object]) -> None:
    """Register ``write(failure)``, which writes ``what`` (e.g. "the filter's estimate") should a later
    stage fail unexpectedly. A second registration under the same ``what`` replaces the first."""
    current = _session.get()
    if current is not None:
        current.kept[what] = write


def absorb(exc: BaseException, stage_name: str) -> str:
    """Record ``exc``, caught by the stage ``stage_name`` that carries on without it; returns its one line.

    Interrupts are not failures: :class:`KeyboardInterrupt` and other non-``Exception`` are re-raised."""
    if not isinstance(exc, Exception):
        raise exc
    line = describe(exc)
    current = _session.get()
    if current is not None:
        current.absorbed.append(Absorbed(stage_of(exc, stage_name), line,
                                         "".join(traceback.format_exception(exc))))
    return line
