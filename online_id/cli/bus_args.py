"""Command-line pieces for CAN: bus selection, DBC and signal map (drivers are imported lazily)."""

from __future__ import annotations

from online_id.errors import OnlineIdError


def add_bus_arguments(p) -> None:
    p.add_argument("--interface", required=True,
                   help="python-can interface: socketcan (e.g. vcan0), udp_multicast, virtual, ...")
    p.add_argument("--channel", required=True, help="bus channel: vcan0, a multicast group like 239.74.163.2, ...")
    p.add_argument("--bus-arg", action="append", default=[], metavar="KEY=VALUE",
                   help="extra keyword for can.Bus, e.g. port=43113 (repeatable)")


def add_dbc_arguments(p, required: bool = False) -> None:
    p.add_argument("--dbc", metavar="FILE", required=required,
                   help="DBC of the frames (default: online-id's own frames)")
    p.add_argument("--signals", metavar="MAP.toml",
                   help="signal map from DBC signals to canonical ones (a file, or a built-in map: online_id,"
                   " toyota_rav4_2017; default: online_id); for a CSV or Parquet table of a logger's own columns,"
                   " a column map (a TOML with a [columns] table: names and units)")


def bus_kwargs(args) -> dict:
    out = {}
    for item in args.bus_arg:
        if "=" not in item:
            raise OnlineIdError(f"--bus-arg {item!r}: expected KEY=VALUE")
        k, v = item.split("=", 1)
        for cast in (int, float):
            try:
                v = cast(v)
                break
            except ValueError:
                continue
        if v in ("true", "false"):
            v = v == "true"
        out[k.strip()] = v
    return out


def open_bus_from_args(args):
    from online_id.drivers.can_bus import open_bus

    return open_bus(args.interface, args.channel, **bus_kwargs(args))
