"""From diagnosis to estimate: the effects a diagnosis named, as ``--effect`` values, and back.

:func:`carry_flags` makes the ``"carry"`` key of ``diagnose --json`` (and the lines ``diagnose`` prints);
:func:`effects_from_diagnosis` reads it for ``--effects-from DIAG.json`` (``estimate``, ``fit``, ``listen``,
``batch``) and the Python API's ``effects_from=``. Each effect starts at the value the diagnosis fitted.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from pathlib import Path

from online_id.effects import Effect, parse_effect_to_estimate
from online_id.errors import OnlineIdError
from online_id.vehicle.parameters import KnownParameters


def carry_flags(effects: Sequence[Effect], known: KnownParameters) -> dict:
    """The diagnosed ``effects`` as ``--effect`` values starting at their fitted values: ``"online"`` those the
    filters carry (``estimate``, ``listen``, ``batch``), ``"fit"`` every one (``fit`` takes every block-mean
    form), ``"not_online"`` the labels of those without a filter form, and the flags as one string each."""
    online = [e.estimate_spec() for e in effects if e.has_filter_form(known)]
    every = [e.estimate_spec() for e in effects]
    return {"fit": every, "online": online,
            "not_online": [e.label for e in effects if not e.has_filter_form(known)],
            "estimate_flags": " ".join(f"--effect {s}" for s in online),
            "fit_flags": " ".join(f"--effect {s}" for s in every)}


def not_online_of(effects_from) -> list[str]:
    """The labels of the effects a diagnosis (a ``diagnose --json`` path or a Diagnosis) named that the filters
    cannot carry (``carry.not_online``); [] for none, or for what is not a readable diagnosis (said elsewhere)."""
    if effects_from is None:
        return []
    carry = getattr(getattr(effects_from, "result", None), "carry", None)
    if carry is None and not hasattr(effects_from, "result"):
        try:
            carry = json.loads(Path(effects_from).read_text(encoding="utf-8")).get("carry")
        except (OSError, UnicodeDecodeError, ValueError, AttributeError):
            return []
    return [str(label) for label in (carry or {}).get("not_online", [])] if isinstance(carry, dict) else []


def effects_from_diagnosis(path: str | Path, online: bool,
                           warn: Callable[[str], None] | None = None) -> list[Effect]:
    """The effects a ``diagnose --json`` file carries: with ``online``, those the filters carry (the others are
    named through ``warn``); else every one. A file that is not a diagnosis is a one-line OnlineIdError."""
    warn = warn or (lambda line: None)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise OnlineIdError(f"--effects-from {path}: cannot read it ({exc.__class__.__name__}: {exc})") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise OnlineIdError(f"--effects-from {path}: not JSON (line {exc.lineno}: {exc.msg})") from None
    if not isinstance(data, dict) or "carry" not in data or "verdict" not in data:
        raise OnlineIdError(f"--effects-from {path}: not the JSON of 'online-id diagnose --json' (no \"carry\""
                            " key; a diagnosis written by an older online-id has none: run diagnose again)")
    carry = data["carry"]
    if not carry:
        warn(f"--effects-from {path}: the diagnosis named no effect; estimating without one")
        return []
    key = "online" if online else "fit"
    specs = carry.get(key) if isinstance(carry, dict) else None
    if not isinstance(specs, list):
        raise OnlineIdError(f"--effects-from {path}: \"carry\" has no list {key!r}: not a diagnose output")
    if online and carry.get("not_online"):
        warn(f"--effects-from {path}: {', '.join(map(str, carry['not_online']))} has no filter form yet: left out"
             " of the online estimate ('online-id fit --effects-from' carries it)")
    try:
        return [parse_effect_to_estimate(str(s)) for s in specs]
    except OnlineIdError as exc:
        raise OnlineIdError(f"--effects-from {path}: {exc}") from None
