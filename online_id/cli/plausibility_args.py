"""The ``--allow-implausible`` flag and the plausibility checks as the sub-commands call them."""

from __future__ import annotations

import sys

from online_id.trust.plausibility import CHECKS, StreamChecker, judge_run, parse_allow


def add_plausibility_argument(p) -> None:
    p.add_argument("--allow-implausible", metavar="CHECK[,CHECK...]",
                   help="accept inputs that fail these plausibility checks (a car that really is like that):"
                   f" {', '.join(CHECKS)} or all; they are then reported as warnings")


def _print_notes(lines: list[str]) -> None:
    for line in lines:
        print(f"online-id: warning: {line}", file=sys.stderr)


def check_run(run, vehicle, args):
    """Judge a whole track run; raise ImplausibleInputError (exit 2) or print the warnings. Returns the
    :class:`~online_id.trust.plausibility.PlausibilityReport` (for the JSON: what was allowed)."""
    allow = parse_allow(getattr(args, "allow_implausible", None))
    report = judge_run(run, vehicle)
    _print_notes(report.enforce(allow))
    return report


def checked_stream(samples, vehicle, args, source: str, max_window_s: float | None, hold: bool = True):
    """``samples`` judged by :class:`online_id.trust.plausibility.StreamChecker` (held back until judged, or
    passed on at once with ``hold=False``)."""
    allow = parse_allow(getattr(args, "allow_implausible", None))
    checker = StreamChecker(vehicle.known, vehicle.prior, allow=allow, max_window_s=max_window_s, source=source,
                            on_notes=_print_notes, hold=hold)
    return checker.check(samples)
