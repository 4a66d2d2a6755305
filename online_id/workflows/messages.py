"""What a workflow has to say while it runs, besides its result.

A workflow (:mod:`online_id.workflows`) never prints. It hands each line to a :class:`Messages`,
which keeps it and, when the front end asked for it, passes it on at once: the CLI prints each kind
where it always went (:func:`online_id.cli.common.printed_messages`), the Python API keeps them on
the result (``Estimate.warnings``). The kinds:

* ``warning``: something about the input or the run a user must see (``online-id: warning: ...``);
* ``note``: how the run was set up, worth knowing (``online-id: note: ...``), e.g. a prior widened;
* ``status``: what the workflow is doing (``no LOG given: using the built-in run``, ``[2/7] ...``);
* ``result``: a line of the result that only the run itself can say (the polish's summary).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

#: The kinds of message, in the order a reader meets them.
KINDS = ("status", "note", "warning", "result")


@dataclass
class Messages:
    """Lines a workflow reports, by kind, in order; ``echo(kind, line)`` sees each as it comes."""

    echo: Callable[[str, str], None] | None = None
    lines: list[tuple[str, str]] = field(default_factory=list)
    #: kinds the front end holds back from ``echo`` to show after its results (the CLI's notes)
    held: tuple[str, ...] = ()

    def _add(self, kind: str, line: str) -> None:
        self.lines.append((kind, line))
        if self.echo is not None:
            self.echo(kind, line)

    def status(self, line: str) -> None:
        self._add("status", line)

    def note(self, line: str) -> None:
        self._add("note", line)

    def warning(self, line: str) -> None:
        self._add("warning", line)

    def result(self, line: str) -> None:
        self._add("result", line)

    def of(self, kind: str) -> list[str]:
        """Every line of one kind, in order."""
        return [line for k, line in self.lines if k == kind]
