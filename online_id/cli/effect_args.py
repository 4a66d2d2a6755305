"""``--effect`` and ``--offsets`` for ``estimate`` and ``fit``: effects of the registry estimated with the 8."""

from __future__ import annotations

from online_id.effects import EFFECTS, OFFSET_CHANNELS, parse_effect_to_estimate


def add_effect_arguments(p, offsets: bool = True) -> None:
    """``--effect NAME[:CHANNEL][:START]`` (repeatable) and, for the online filters, ``--offsets``."""
    p.add_argument("--effect", action="append", default=[], metavar="NAME[:CHANNEL]",
                   help="estimate an effect's parameters with the 8 (repeatable; the names of 'simulate --effect'"
                   " and 'diagnose --effects'; a channel where the effect has one, e.g. sensor_bias:yaw_rate;"
                   " an optional starting value after another ':'): "
                   + "; ".join(f"{n} ({c.summary})" for n, c in EFFECTS.items()))
    if offsets:
        p.add_argument("--offsets", action="store_true",
                       help="learn the sensor offsets of " + ", ".join(OFFSET_CHANNELS) + " as filter states"
                       " (those of the channels used; the same as --effect sensor_bias:CHANNEL for each)")


def effects_of(args) -> list:
    """The effects ``--effect`` asks for (a one-line OnlineIdError for an unknown name or channel)."""
    return [parse_effect_to_estimate(t) for t in args.effect]


def filter_effects_of(args, known) -> list:
    """The effects ``--effect`` asks for, checked up front to have a filter form and to be asked for once
    (a one-line OnlineIdError before any data is read, so no data warning precedes it)."""
    from online_id.filters.augment import Augmentation

    effects = effects_of(args)
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
