"""``--effect``, ``--effects-from`` and ``--offsets``: effects of the registry estimated with the 8 (resolved by
:func:`online_id.workflows.inputs.effects_of`)."""

from __future__ import annotations

from online_id.effects import EFFECTS, OFFSET_CHANNELS


def add_effect_arguments(p, offsets: bool = True) -> None:
    """``--effect NAME[:CHANNEL][:START]`` (repeatable) and, for the online filters, ``--offsets``."""
    p.add_argument("--effect", action="append", default=[], metavar="NAME[:CHANNEL]",
                   help="estimate an effect's parameters with the 8 (repeatable; the names of 'simulate --effect'"
                   " and 'diagnose --effects'; a channel where the effect has one, e.g. sensor_bias:yaw_rate;"
                   " optional starting values after another ':', one per parameter, e.g. tire_saturation_axles:0.9:1.0;"
                   " the effects table of the docs says what each adds to the filters): "
                   + "; ".join(f"{n} ({c.summary})" for n, c in EFFECTS.items()))
    p.add_argument("--effects-from", metavar="DIAG.json",
                   help="estimate the effects a 'diagnose --json' output named, starting at its fitted values"
                   " (with any --effect; an --effect of the same effect and channel wins)")
    if offsets:
        p.add_argument("--offsets", action="store_true",
                       help="learn the sensor offsets of " + ", ".join(OFFSET_CHANNELS) + " as filter states"
                       " (those of the channels used; the same as --effect sensor_bias:CHANNEL for each)")


def extra_state_lines(extra: dict) -> list[str]:
    """Printable lines for the estimated offsets and effect parameters."""
    lines = []
    for channel, v in extra.get("offsets", {}).items():
        lines.append(f"offset {channel}: {v['value']:.5g} ± {v['std']:.2g} {v['unit']}")
    for label, params in extra.get("effects", {}).items():
        for name, v in params.items():
            lines.append(f"effect {label} {name}: {v['value']:.5g} ± {v['std']:.2g} {v['unit']}")
    return lines
