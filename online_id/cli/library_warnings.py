"""Warnings from the libraries (and from online-id's own modules) reported in the tool's words.

Python prints a warning with the file and line that issued it: a site-packages path and a line
of someone else's source, in bursts when a filter update repeats the same ill-conditioned solve.
Inside :func:`reported_warnings` each kind of warning is shown once, as one line
``online-id: warning: ...``, and counted; :func:`counts` gives the counts for the JSON
(``"warning_counts"``).
"""

from __future__ import annotations

import sys
import warnings
from collections import Counter
from collections.abc import Iterator
from contextlib import contextmanager

#: Words for the warnings the numerical libraries are known to give, by category name.
KNOWN = {
    "LinAlgWarning": "an ill-conditioned matrix in a linear solve (the result may be inaccurate)",
    "ComplexWarning": "a complex value was cut to its real part",
    "OptimizeWarning": "the optimiser could not estimate something it was asked for",
    "IntegrationWarning": "a numerical integral may be inaccurate",
}

_counts: Counter = Counter()
_shown: set[str] = set()


def _key(category: type, module: str) -> str:
    """The JSON key: the category, and where it came from when not from online-id itself."""
    origin = module.split(".")[0] if module else ""
    return category.__name__ if origin in ("", "online_id", "drivers", "replay") else f"{origin}.{category.__name__}"


def _show(message, category, filename, lineno, file=None, line=None) -> None:
    module = _module_of(filename)
    key = _key(category, module)
    _counts[key] += 1
    if _counts[key] > 1:
        return
    text = str(message).strip().splitlines()[0] if str(message).strip() else category.__name__
    origin = key.split(".")[0] if "." in key else ""
    if origin:
        words = KNOWN.get(category.__name__)
        text = f"{words} ({origin}: {text})" if words else f"{origin}: {text}"
    _shown.add(str(message).strip())
    print(f"online-id: warning: {text} (repeats are counted, not shown)", file=sys.stderr)


def _module_of(filename: str) -> str:
    """The top-level package a file belongs to, from its path (site-packages/<pkg>/...)."""
    parts = filename.replace("\\", "/").split("/")
    for marker in ("site-packages", "dist-packages"):
        if marker in parts:
            i = parts.index(marker)
            return parts[i + 1] if i + 1 < len(parts) else ""
    for own in ("online_id", "drivers", "replay"):
        if own in parts:
            return own
    return ""


@contextmanager
def reported_warnings() -> Iterator[None]:
    """Within the block, every warning is counted and each kind shown once (see the module docstring)."""
    _counts.clear()
    _shown.clear()
    with warnings.catch_warnings():
        warnings.simplefilter("always")  # count every one: the default filter would hide repeats from the count
        for hidden in (DeprecationWarning, PendingDeprecationWarning):  # for developers, not users
            warnings.simplefilter("ignore", hidden)
        warnings.showwarning = _show
        yield


def counts() -> dict[str, int]:
    """Warnings seen so far in this command, by kind."""
    return dict(_counts)


def was_shown(text: str) -> bool:
    """Whether a warning with this message was already printed (so a command need not repeat it)."""
    return text.strip() in _shown
