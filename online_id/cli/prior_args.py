"""The flags that control the prior: ``--fix NAME=VALUE`` / ``--fix NAME`` and ``--keep-prior-std`` (parsed by
:func:`online_id.workflows.inputs.parse_fix`)."""

from __future__ import annotations

from online_id.vehicle.parameters import PARAMETER_NAMES, PARAMETER_UNITS


def add_prior_arguments(p, *, keep_std: bool = True) -> None:
    p.add_argument("--fix", action="append", metavar="NAME[=VALUE]", default=[],
                   help="hold a parameter fixed at VALUE (SI units: "
                   + ", ".join(f"{n} {PARAMETER_UNITS[n]}" for n in PARAMETER_NAMES)
                   + "), or at its prior value without =VALUE; repeatable")
    if keep_std:
        p.add_argument("--keep-prior-std", action="store_true",
                       help="start from the vehicle file's prior σ as written (by default σ under 100 %% are"
                       " widened to 100 %%, and the widening is reported)")
