"""Exceptions that reach the user as one readable line.

Every error the program raises on purpose derives from :class:`OnlineIdError`;
the CLI prints its message and exits non-zero without a traceback.  Messages
say *what* is wrong and *where* (file, line, column or key).
"""

from __future__ import annotations


class OnlineIdError(Exception):
    """Base class for errors meant for the user, not for a developer."""


class VehicleFileError(OnlineIdError, ValueError):
    """A vehicle description (TOML) is missing a key or holds an impossible value."""


class LogFormatError(OnlineIdError, ValueError):
    """A track-run log cannot be used: missing column, bad cell, wrong unit, bad time."""


class DivergedWarning(RuntimeWarning):
    """An online filter broke down in a burst of resets and stopped learning its parameters (its own kind, so
    that a front end that shows each kind of warning once does not hide it behind the first reset's)."""


class SensorOffsetWarning(RuntimeWarning):
    """A parameter-free check (a_y − V·r) shows a sensor offset the filter does not estimate."""
