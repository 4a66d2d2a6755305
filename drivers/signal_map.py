"""Signal maps: which DBC signal is which canonical signal, with unit conversion and sign.

A map is a small TOML file (see ``data/toyota_rav4_2017_signals.toml``)::

    name = "mycar"
    dbc = "mycar.dbc"              # optional; relative to the map file
    trigger = "KINEMATICS"         # the message whose arrival completes a sample
    stale_after_s = 0.1            # a signal older than this is not used (and is counted)
    channel = "can0"               # optional: only frames from this channel
    counter = "COUNTER"            # optional: frames of one sample share this signal's value
    time = { message = "M", signal = "S" }   # optional: sample time from a signal, not the frame

    [signals.yaw_rate]             # canonical name (online_id.stream.samples.MEASURED_CHANNELS + inputs)
    message = "KINEMATICS"
    signal = "YAW_RATE"            # or a list of signals that are summed
    scale = 0.0174533              # canonical = scale * (sum of signals) + offset
    offset = 0.0

Canonical names: steering_wheel_angle [rad], speed [m/s], yaw_rate [rad/s],
lateral_acceleration [m/s²], roll_angle [rad], roll_rate [rad/s]. The two inputs
(steering_wheel_angle, speed) are required.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

from online_id.errors import OnlineIdError

#: The signals a map can name: the inputs, the measured channels, and the longitudinal acceleration (an input of
#: ``load_transfer``'s axle loads, not a measured channel).
CANONICAL = ("steering_wheel_angle", "speed", "yaw_rate", "lateral_acceleration", "roll_angle", "roll_rate",
             "lateral_velocity", "longitudinal_acceleration")
REQUIRED = ("steering_wheel_angle", "speed")


class SignalMapError(OnlineIdError, ValueError):
    """A signal map that cannot be used with its DBC."""


@dataclass(frozen=True)
class SignalSpec:
    message: str
    signals: tuple[str, ...]
    scale: float = 1.0
    offset: float = 0.0


#: A value is stale only when older than the map's stale_after_s and than this many of its own message's
#: periods (drivers.assembler, drivers.mdf_signals): the 0.1 s default would leave out half the values of a
#: 10 Hz message, whose latest value is up to 0.1 s old by design.
STALE_PERIODS = 2.5


@dataclass(frozen=True)
class SignalMap:
    name: str
    trigger: str
    signals: dict[str, SignalSpec]
    stale_after_s: float = 0.1
    channel: str | None = None
    counter: str | None = None
    time: tuple[str, str] | None = None
    dbc: Path | None = None
    source: str = ""
    messages: tuple[str, ...] = field(default=())

    def check_against(self, db) -> None:
        """Every message and signal named here must exist in the cantools database ``db``."""
        names = {m.name: m for m in db.messages}
        wanted = [(self.trigger, None)] + [(s.message, sig) for s in self.signals.values() for sig in s.signals]
        if self.time:
            wanted.append(self.time)
        for msg, sig in wanted:
            if msg not in names:
                raise SignalMapError(f"{self.source}: message {msg!r} is not in the DBC")
            if sig is not None and sig not in [s.name for s in names[msg].signals]:
                raise SignalMapError(f"{self.source}: signal {sig!r} is not in message {msg!r} of the DBC")
            if self.counter and sig is not None and self.counter not in [s.name for s in names[msg].signals]:
                raise SignalMapError(f"{self.source}: message {msg!r} has no counter signal {self.counter!r}")


def builtin_map_path(name: str) -> Path:
    """Path of a map shipped with online-id: ``online_id`` or ``toyota_rav4_2017``."""
    p = resources.files("online_id.drivers") / "data" / f"{name}_signals.toml"
    return Path(str(p))


def builtin_dbc_path() -> Path:
    """Path of online-id's own DBC."""
    return Path(str(resources.files("online_id.drivers") / "data" / "online_id.dbc"))


def load_signal_map(path: str | Path) -> SignalMap:
    """Read and validate a signal map (a path, or the name of a built-in map)."""
    p = Path(path)
    if not p.is_file() and builtin_map_path(str(path)).is_file():
        p = builtin_map_path(str(path))
    src = str(p)
    try:
        data = tomllib.loads(p.read_text(encoding="utf-8"))
    except (FileNotFoundError, IsADirectoryError):
        raise SignalMapError(f"{src}: no such signal map (built-in: online_id, toyota_rav4_2017)") from None
    except tomllib.TOMLDecodeError as exc:
        raise SignalMapError(f"{src}: not valid TOML: {exc}") from None
    for key in ("trigger", "signals"):
        if key not in data:
            raise SignalMapError(f"{src}: missing key {key!r}")
    specs = {}
    for name, entry in data["signals"].items():
        if name not in CANONICAL:
            raise SignalMapError(f"{src}: unknown canonical signal {name!r}; choose from {', '.join(CANONICAL)}")
        if not isinstance(entry, dict) or "message" not in entry or "signal" not in entry:
            raise SignalMapError(f"{src}: signals.{name} needs 'message' and 'signal'")
        sigs = entry["signal"] if isinstance(entry["signal"], list) else [entry["signal"]]
        scale, offset = entry.get("scale", 1.0), entry.get("offset", 0.0)
        if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in (scale, offset)) or scale == 0:
            raise SignalMapError(f"{src}: signals.{name}: scale must be a non-zero number, offset a number")
        specs[name] = SignalSpec(entry["message"], tuple(sigs), float(scale), float(offset))
    missing = [r for r in REQUIRED if r not in specs]
    if missing:
        raise SignalMapError(f"{src}: missing required signal(s) {', '.join(missing)}")
    time = data.get("time")
    if time is not None and not (isinstance(time, dict) and {"message", "signal"} <= set(time)):
        raise SignalMapError(f"{src}: 'time' must be {{message = ..., signal = ...}}")
    dbc = data.get("dbc")
    stale = data.get("stale_after_s", 0.1)
    if not isinstance(stale, (int, float)) or stale <= 0:
        raise SignalMapError(f"{src}: stale_after_s must be a positive number of seconds")
    messages = tuple(sorted({s.message for s in specs.values()} | {data["trigger"]}))
    return SignalMap(
        name=str(data.get("name", p.stem)), trigger=data["trigger"], signals=specs, stale_after_s=float(stale),
        channel=data.get("channel"), counter=data.get("counter"),
        time=(time["message"], time["signal"]) if time else None,
        dbc=(p.parent / dbc) if dbc else None, source=src, messages=messages,
    )
