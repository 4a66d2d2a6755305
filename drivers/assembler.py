"""From CAN frames to samples: decode through a DBC, map to canonical names, assemble multi-rate frames.

Each mapped message's latest decoded values are kept with their arrival time. When
the map's trigger message arrives, a :class:`~online_id.samples.Sample` is emitted
with the latest value of every canonical signal; a value older than
``stale_after_s`` (or, with a counter, from another sample) is left out and
counted. Frames are accounted for, never silently dropped: unknown IDs, frames of
the wrong length and undecodable payloads are counted per ID.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import can
import cantools

from drivers.channels import channel_option, normalise_channel
from drivers.signal_map import SignalMap
from online_id.samples import Sample


@dataclass
class FrameStats:
    """What the assembler saw. Counters by CAN ID (hex string) or by canonical signal."""

    frames: int = 0
    used_frames: int = 0
    samples: int = 0
    unknown_ids: Counter = field(default_factory=Counter)
    wrong_length: Counter = field(default_factory=Counter)
    undecodable: Counter = field(default_factory=Counter)
    other_channel: int = 0
    stale: Counter = field(default_factory=Counter)
    counter_mismatch: Counter = field(default_factory=Counter)
    incomplete_samples: int = 0
    trigger_frames: int = 0
    channels_seen: Counter = field(default_factory=Counter)

    def to_dict(self) -> dict:
        return {
            "frames": self.frames, "used_frames": self.used_frames, "samples": self.samples,
            "unknown_ids": dict(self.unknown_ids), "unknown_frames": sum(self.unknown_ids.values()),
            "wrong_length": dict(self.wrong_length), "undecodable": dict(self.undecodable),
            "other_channel": self.other_channel, "stale": dict(self.stale),
            "counter_mismatch": dict(self.counter_mismatch), "incomplete_samples": self.incomplete_samples,
            "trigger_frames": self.trigger_frames, "channels_seen": {str(k): v for k, v in self.channels_seen.items()},
        }

    def problems(self) -> list[str]:
        """One line per kind of problem met, naming IDs and signals."""
        out = []
        if self.unknown_ids:
            ids = ", ".join(f"{k} ({v})" for k, v in sorted(self.unknown_ids.items())[:8])
            more = "" if len(self.unknown_ids) <= 8 else f" and {len(self.unknown_ids) - 8} more"
            out.append(f"{sum(self.unknown_ids.values())} frame(s) with IDs not used by the map ignored: {ids}{more}")
        for what, counter in (("wrong length", self.wrong_length), ("undecodable payload", self.undecodable)):
            if counter:
                out.append(f"{sum(counter.values())} frame(s) with {what}: "
                           + ", ".join(f"ID {k}: {v}" for k, v in sorted(counter.items())))
        if self.stale:
            out.append("stale signal(s) left out of samples: "
                       + ", ".join(f"{k} in {v} sample(s)" for k, v in sorted(self.stale.items())))
        if self.counter_mismatch:
            out.append("values from another sample (counter mismatch) left out: "
                       + ", ".join(f"{k} {v}" for k, v in sorted(self.counter_mismatch.items())))
        return out


class FrameAssembler:
    """Feed :class:`can.Message` frames; get samples when the trigger message arrives."""

    def __init__(self, db: cantools.database.can.Database, signal_map: SignalMap, filter_channel: bool = True,
                 channel: str | None = None):
        """``filter_channel``: keep only frames of the map's ``channel`` (or of ``channel`` when given; ``"any"``
        keeps all), compared as :func:`drivers.channels.normalise_channel` names; a live bus is one channel."""
        signal_map.check_against(db)
        self.map = signal_map
        self._channel = channel_option(channel or signal_map.channel) if filter_channel else None
        self.stats = FrameStats()
        self._messages = {}
        for name in signal_map.messages:
            m = db.get_message_by_name(name)
            self._messages[m.frame_id] = m
        self._trigger_id = db.get_message_by_name(signal_map.trigger).frame_id
        self._latest: dict[str, tuple[float, dict]] = {}  # message name -> (arrival time, decoded)

    def feed(self, msg: can.Message) -> Sample | None:
        st = self.stats
        st.frames += 1
        channel = normalise_channel(msg.channel)
        st.channels_seen[channel] += 1
        if self._channel is not None and channel is not None and channel != self._channel:
            st.other_channel += 1
            return None
        spec = self._messages.get(msg.arbitration_id)
        if spec is None or msg.is_error_frame or msg.is_remote_frame:
            st.unknown_ids[f"0x{msg.arbitration_id:X}"] += 1
            return None
        key = f"0x{msg.arbitration_id:X}"
        if len(msg.data) != spec.length:
            st.wrong_length[key] += 1
            return None
        try:
            decoded = spec.decode(bytes(msg.data), decode_choices=False)
        except Exception:  # cantools raises several types for a bad payload
            st.undecodable[key] += 1
            return None
        st.used_frames += 1
        self._latest[spec.name] = (msg.timestamp, decoded)
        if msg.arbitration_id != self._trigger_id:
            return None
        st.trigger_frames += 1
        return self._assemble(msg.timestamp, decoded)

    def _assemble(self, now: float, trigger_values: dict) -> Sample | None:
        m, st = self.map, self.stats
        counter = trigger_values.get(m.counter) if m.counter else None
        values = {}
        for name, spec in m.signals.items():
            entry = self._latest.get(spec.message)
            if entry is None:
                continue
            t, decoded = entry
            if now - t > m.stale_after_s:
                st.stale[name] += 1
                continue
            if counter is not None and decoded.get(m.counter) != counter:
                st.counter_mismatch[name] += 1
                continue
            values[name] = spec.scale * sum(float(decoded[s]) for s in spec.signals) + spec.offset
        if "steering_wheel_angle" not in values or "speed" not in values:
            st.incomplete_samples += 1
            return None
        if m.time is not None:
            t_entry = self._latest.get(m.time[0])
            time = float(t_entry[1][m.time[1]]) if t_entry is not None else now
        else:
            time = now
        st.samples += 1
        return Sample(time=time, steering_wheel_angle=values["steering_wheel_angle"], speed=values["speed"],
                      yaw_rate=values.get("yaw_rate"), lateral_acceleration=values.get("lateral_acceleration"),
                      roll_angle=values.get("roll_angle"), roll_rate=values.get("roll_rate"))
