"""The flags that control the prior: ``--fix NAME=VALUE`` / ``--fix NAME`` and ``--keep-prior-std``."""

from __future__ import annotations

import math

from online_id.errors import OnlineIdError
from online_id.vehicle.parameters import PARAMETER_NAMES, PARAMETER_UNITS, Parameters


def add_prior_arguments(p, *, keep_std: bool = True) -> None:
    p.add_argument("--fix", action="append", metavar="NAME[=VALUE]", default=[],
                   help="hold a parameter fixed at VALUE (SI units: "
                   + ", ".join(f"{n} {PARAMETER_UNITS[n]}" for n in PARAMETER_NAMES)
                   + "), or at its prior value without =VALUE; repeatable")
    if keep_std:
        p.add_argument("--keep-prior-std", action="store_true",
                       help="start from the vehicle file's prior σ as written (by default σ under 100 %% are"
                       " widened to 100 %%, and the widening is reported)")


def parse_fix(items: list[str], prior: Parameters) -> dict[str, float]:
    """``["Mzz=1600", "b1"]`` → ``{"Mzz": 1600.0, "b1": <prior b1>}``; bad input is an :class:`OnlineIdError`."""
    fixed: dict[str, float] = {}
    for item in items:
        name, sep, text = (part.strip() for part in item.partition("="))
        if name not in PARAMETER_NAMES:
            raise OnlineIdError(f"--fix {item}: unknown parameter {name!r}; choose from {', '.join(PARAMETER_NAMES)}")
        if name in fixed:
            raise OnlineIdError(f"--fix {item}: {name} is fixed twice")
        if not sep:
            fixed[name] = float(getattr(prior, name))
            continue
        try:
            value = float(text)
        except ValueError:
            raise OnlineIdError(f"--fix {item}: {text!r} is not a number (SI units: {PARAMETER_UNITS[name]})") from None
        if not (math.isfinite(value) and value > 0):
            raise OnlineIdError(f"--fix {item}: the value must be positive and finite ({PARAMETER_UNITS[name]})")
        fixed[name] = value
    if len(fixed) == len(PARAMETER_NAMES):
        raise OnlineIdError("--fix: every parameter is fixed; nothing left to estimate")
    return fixed
