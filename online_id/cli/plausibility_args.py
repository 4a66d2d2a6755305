"""The ``--allow-implausible`` flag (the workflows judge the inputs: :mod:`online_id.trust.plausibility`)."""

from __future__ import annotations

from online_id.trust.plausibility import CHECKS


def add_plausibility_argument(p) -> None:
    p.add_argument("--allow-implausible", metavar="CHECK[,CHECK...]",
                   help="accept inputs that fail these plausibility checks (a car that really is like that):"
                   f" {', '.join(CHECKS)} or all; they are then reported as warnings")
