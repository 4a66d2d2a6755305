"""``--effect`` and ``--offsets`` for ``estimate`` and ``fit``: effects of the registry estimated with the 8."""

from __future__ import annotations

import sys

from online_id.effects import EFFECTS, OFFSET_CHANNELS, parse_effect_to_estimate


def add_effect_arguments(p, offsets: bool = True) -> None:
    """``--effect NAME[:CHANNEL][:START]`` (repeatable) and, for the online filters, ``--offsets``."""
    p.add_argument("--effect", action="append", default=[], metavar="NAME[:CHANNEL]",
                   help="estimate an effect's parameters with the 8 (repeatable; the names of 'simulate --effect'"
                   " and 'diagnose --effects'; a channel where the effect has one, e.g. sensor_bias:yaw_rate;"
                   " an optional starting value after another ':'): "
                   + "; ".join(f"{n} ({c.summary})" for n, c in EFFECTS.items()))
    p.add_argument("--effects-from", metavar="DIAG.json",
                   help="estimate the effects a 'diagnose --json' output named, starting at its fitted values"
                   " (with any --effect; an --effect of the same effect and channel wins)")
    if offsets:
        p.add_argument("--offsets", action="store_true",
                       help="learn the sensor offsets of " + ", ".join(OFFSET_CHANNELS) + " as filter states"
                       " (those of the channels used; the same as --effect sensor_bias:CHANNEL for each)")


def effects_of(args, online: bool = False) -> list:
    """The effects ``--effect`` and ``--effects-from`` ask for (a one-line OnlineIdError for an unknown name or
    channel, or a file that is not a diagnosis). ``online``: only those of the diagnosis the filters carry
    (the others are named in a warning)."""
    given = [parse_effect_to_estimate(t) for t in args.effect]
    path = getattr(args, "effects_from", None)
    if path is None:
        return given
    labels = {e.label for e in given}
    from online_id.diagnosis.carry import effects_from_diagnosis

    return given + [e for e in effects_from_diagnosis(path, online, warn=_warn) if e.label not in labels]


def _warn(line: str) -> None:
    print(f"online-id: warning: {line}", file=sys.stderr, flush=True)


def filter_effects_of(args, known) -> list:
    """The effects ``--effect`` and ``--effects-from`` ask for, checked up front to have a filter form and to be
    asked for once (a one-line OnlineIdError before any data is read, so no data warning precedes it)."""
    from online_id.filters.augment import Augmentation

    effects = effects_of(args, online=True)
    Augmentation.from_effects(effects, known)
    return effects


def offsets_of(args, channels) -> list[str] | bool:
    """The offset channels ``--offsets`` asks for, among the measured ``channels`` (the steering is always there)."""
    if not getattr(args, "offsets", False):
        return False
    return [c for c in OFFSET_CHANNELS if c in channels or c == "steering_wheel_angle"]


def extra_state_lines(extra: dict) -> list[str]:
    """Printable lines for the estimated offsets and effect parameters."""
    lines = []
    for channel, v in extra.get("offsets", {}).items():
        lines.append(f"offset {channel}: {v['value']:.5g} ± {v['std']:.2g} {v['unit']}")
    for label, params in extra.get("effects", {}).items():
        for name, v in params.items():
            lines.append(f"effect {label} {name}: {v['value']:.5g} ± {v['std']:.2g} {v['unit']}")
    return lines
