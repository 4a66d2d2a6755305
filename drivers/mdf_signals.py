"""MDF4/MDF3 files of decoded physical signals (what a data logger records) as a sample source.

A channel becomes a canonical signal in one of two ways:

* **by name**: a channel named like a track-run column (``yaw_rate``, ``speed``, ...), in any of
  the units in :data:`UNIT_FACTORS` (converted to SI); a channel without a unit is taken as SI
  and said so in :meth:`MdfSignalSource.problems`;
* **by the signal map** (``--signals``): a channel named like the map's DBC signal (``YAW_RATE``)
  or ``MESSAGE.SIGNAL`` (``KINEMATICS.YAW_RATE``), converted with the map's scale and offset as the
  raw CAN signal would be (tried before the track-run name; a map signal that sums two DBC signals
  has no single channel and is found by its track-run name only).

A unit that does not fit the column (``km/h`` for a yaw rate) is an error naming the channel.
Channels have their own time bases: a sample is made at each time of the trigger channel (the
map's trigger message, else ``yaw_rate``) with the latest value of every other channel, which is
left out, and counted, when older than ``stale_after_s`` (as :mod:`online_id.drivers.assembler` does for
frames).
"""

from __future__ import annotations

import gc
import math
import sys
from collections import Counter
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from online_id.drivers.base import NoSamplesError, SampleSource
from online_id.drivers.signal_map import CANONICAL, STALE_PERIODS, SignalMap

from online_id.errors import OnlineIdError
from online_id.stream.samples import MEASURED_CHANNELS, Sample
from online_id.units import G

#: Per canonical signal: accepted units and the factor to SI.
_DEG = math.pi / 180.0
UNIT_FACTORS: dict[str, dict[str, float]] = {
    "steering_wheel_angle": {"rad": 1.0, "deg": _DEG, "°": _DEG},
    "roll_angle": {"rad": 1.0, "deg": _DEG, "°": _DEG},
    "yaw_rate": {"rad/s": 1.0, "deg/s": _DEG, "°/s": _DEG},
    "roll_rate": {"rad/s": 1.0, "deg/s": _DEG, "°/s": _DEG},
    "speed": {"m/s": 1.0, "km/h": 1 / 3.6, "kph": 1 / 3.6, "mph": 0.44704},
    "lateral_acceleration": {"m/s²": 1.0, "m/s^2": 1.0, "m/s2": 1.0, "g": G},
    "lateral_velocity": {"m/s": 1.0, "km/h": 1 / 3.6, "kph": 1 / 3.6, "mph": 0.44704},
    "longitudinal_acceleration": {"m/s²": 1.0, "m/s^2": 1.0, "m/s2": 1.0, "g": G},
}
#: A value older than this at a sample's time is stale when no map says otherwise [s] (the built-in
#: RAV4 map's value: a few periods of a 10-100 Hz logger channel).
DEFAULT_STALE_AFTER_S = 0.1


class MdfError(OnlineIdError, ValueError):
    """An MDF file that cannot be read or mapped."""


def open_mdf(path: Path):
    """The asammdf ``MDF`` of ``path``, with a one-line error for a missing or corrupt file."""
    try:
        from asammdf import MDF
    except ImportError as exc:  # a declared dependency; only a broken install gets here
        raise MdfError(f"{path}: reading MDF needs asammdf: {exc}") from None
    if not path.exists():
        raise MdfError(f"{path}: no such file")
    hook = sys.unraisablehook
    try:
        try:
            return MDF(str(path))
        except Exception as exc:  # asammdf raises many types for a corrupt file
            message = f"{path}: not a readable MDF file: {type(exc).__name__}: {exc}"
            # the half-built MDF object is freed when this block ends, and its __del__ fails (asammdf 8.8):
            # keep that traceback off the user's screen
            sys.unraisablehook = _ignore_unraisable
        gc.collect()
    finally:
        sys.unraisablehook = hook
    raise MdfError(message)


def _ignore_unraisable(_unraisable) -> None:
    """An unraisable-exception hook that drops it (see :func:`open_mdf`)."""


def is_bus_logging(mdf) -> bool:
    """True for an ASAM bus-logging MDF (raw CAN frames, as python-can's MF4Writer writes)."""
    return any(name.startswith("CAN_DataFrame") for name in mdf.channels_db)


class MdfSignalSource(SampleSource):
    """Samples from the decoded signals of an MDF file (see the module docstring)."""

    def __init__(self, path: str | Path, signal_map: SignalMap | None = None, mdf=None):
        super().__init__()
        self.path = Path(path)
        self.name = str(self.path)
        self.map = signal_map
        self.stale_after_s = signal_map.stale_after_s if signal_map else DEFAULT_STALE_AFTER_S
        self.stale: Counter = Counter()
        self.notes: list[str] = []
        mdf = mdf if mdf is not None else open_mdf(self.path)
        try:
            self.signals = self._find(mdf)  # canonical -> (timestamps, SI values)
        finally:
            mdf.close()
        missing = [c for c in ("steering_wheel_angle", "speed") if c not in self.signals]
        if missing:
            how = f"the map {signal_map.name}'s signals" if signal_map else "track-run column names"
            raise MdfError(f"{self.path}: no channel for {', '.join(missing)} (looked for {how});"
                           f" channels: {self._listing}")
        self.trigger = self._trigger_signal()

    @property
    def channels(self) -> list[str]:
        return [c for c in MEASURED_CHANNELS if c in self.signals]

    def _names_for(self, canonical: str) -> list[tuple[str, float, float, bool]]:
        """Channel names to look for: (name, scale, offset, unit from the map)."""
        by_name = [(canonical, 1.0, 0.0, False)]
        spec = self.map.signals.get(canonical) if self.map is not None else None
        if spec is None or len(spec.signals) != 1:  # a sum of signals has no single decoded channel
            return by_name
        sig = spec.signals[0]
        return [(f"{spec.message}.{sig}", spec.scale, spec.offset, True), (sig, spec.scale, spec.offset, True),
                *by_name]

    def _find(self, mdf) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        names = [n for n in mdf.channels_db if n not in ("t", "time", "timestamps")]
        self._listing = ", ".join(sorted(names)[:12]) + (" ..." if len(names) > 12 else "")
        out = {}
        for canonical in CANONICAL:
            for name, scale, offset, by_map in self._names_for(canonical):
                if name not in mdf.channels_db:
                    continue
                try:
                    sig = mdf.get(name)
                except Exception as exc:  # a channel asammdf cannot decode
                    raise MdfError(f"{self.path}: channel {name!r}: unreadable: {exc}") from None
                values = np.asarray(sig.samples, dtype=float)
                times = np.asarray(sig.timestamps, dtype=float)
                if by_map:
                    values = scale * values + offset
                else:
                    values = values * self._unit_factor(canonical, name, str(sig.unit or "").strip())
                good = np.isfinite(values)
                if not good.all():
                    self.notes.append(f"channel {name}: {int((~good).sum())} NaN/inf value(s) left out")
                if len(times) > 1 and np.any(np.diff(times[good]) <= 0):
                    raise MdfError(f"{self.path}: channel {name!r}: time does not increase")
                out[canonical] = (times[good], values[good])
                break
        return out

    def _unit_factor(self, canonical: str, name: str, unit: str) -> float:
        units = UNIT_FACTORS[canonical]
        if unit == "":
            self.notes.append(f"channel {name} has no unit: taken as {next(iter(units))}")
            return 1.0
        if unit not in units:
            raise MdfError(f"{self.path}: channel {name!r}: unit {unit!r} is not one for {canonical}"
                           f" (accepted: {', '.join(units)})")
        return units[unit]

    def _trigger_signal(self) -> str:
        if self.map is not None:
            for c, spec in self.map.signals.items():
                if spec.message == self.map.trigger and c in self.signals:
                    return c
        for c in ("yaw_rate", "lateral_acceleration", "steering_wheel_angle"):
            if c in self.signals:
                return c
        return "speed"

    def _samples(self) -> Iterator[Sample]:
        t_master = self.signals[self.trigger][0]
        columns = {}
        for c, (t, v) in self.signals.items():
            idx = np.searchsorted(t, t_master, side="right") - 1
            ok = idx >= 0
            age = np.where(ok, t_master - t[np.maximum(idx, 0)], np.inf)
            # stale beyond the map's age and STALE_PERIODS of the signal's own period (a 10 Hz channel's latest
            # value is up to 0.1 s old by design)
            period = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
            fresh = age <= max(self.stale_after_s, STALE_PERIODS * period)
            self.stale[c] += int((~fresh).sum())
            columns[c] = np.where(fresh, v[np.maximum(idx, 0)], np.nan).tolist()
        if not self.stale[self.trigger]:
            del self.stale[self.trigger]
        times = t_master.tolist()
        yielded = 0
        for k, time in enumerate(times):
            row = {c: columns[c][k] for c in columns}
            row = {c: (None if math.isnan(v) else v) for c, v in row.items()}
            if row.get("steering_wheel_angle") is None or row.get("speed") is None:
                continue
            yielded += 1
            yield Sample(time=time, **row)
        if yielded == 0:
            raise NoSamplesError(f"{self.path}: no usable sample: steering_wheel_angle or speed is stale (older"
                                 f" than {self.stale_after_s:g} s) at every time of {self.trigger}")

    def report(self) -> dict:
        return {"mdf_channels": {c: len(t) for c, (t, _) in self.signals.items()}, "trigger": self.trigger,
                "stale": {k: v for k, v in self.stale.items() if v}}

    def problems(self) -> list[str]:
        out = list(self.notes)
        stale = {k: v for k, v in self.stale.items() if v}
        if stale:
            out.append("stale signal(s) left out of samples: "
                       + ", ".join(f"{k} in {v} sample(s)" for k, v in sorted(stale.items())))
        return out
