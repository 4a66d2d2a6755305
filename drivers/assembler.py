"""From CAN frames to samples: decode through a DBC, map to canonical names, assemble multi-rate frames.

Each mapped message's latest decoded values are kept with their arrival time. When
the map's trigger message arrives, a :class:`~online_id.stream.samples.Sample` is emitted
with the latest value of every canonical signal; a value older than
``stale_after_s`` (and than :data:`STALE_PERIODS` of its own message's period: a 10 Hz message's latest
value is up to 0.1 s old by design) or, with a counter, from another sample, is left out and
counted. Frames are accounted for, never silently dropped: unknown IDs, frames of
the wrong length and undecodable payloads are counted per ID.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import can
import cantools
from online_id.drivers.channels import channel_option, normalise_channel
from online_id.drivers.loss import LossCounter
from online_id.drivers.signal_map import STALE_PERIODS, SignalMap

from online_id.stream.samples import Sample

#: Weight of the newest interval in a message's running period (an exponential mean: no per-frame sort).
PERIOD_WEIGHT = 0.05


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
    #: loss (drivers/loss.py): frames missing by message (COUNTER gaps), samples missing (time gaps)
    lost_frames: Counter = field(default_factory=Counter)
    lost_samples: int = 0
    first_loss_time: float | None = None
    signals: tuple[str, ...] = ()
    trigger_frames: int = 0
    channels_seen: Counter = field(default_factory=Counter)
    #: frames with an ID the map uses that came on another channel than the one selected, by channel
    wanted_on_other_channel: Counter = field(default_factory=Counter)

    @property
    def lost_by_signal(self) -> dict[str, int]:
        """Per mapped signal: samples that went without it (lost whole, or left out as stale or from
        another sample)."""
        return {n: self.lost_samples + self.stale[n] + self.counter_mismatch[n] for n in self.signals}

    def loss_fraction(self) -> float:
        """Lost samples over the samples there should have been."""
        expected = self.samples + self.lost_samples
        return self.lost_samples / expected if expected else 0.0

    def to_dict(self) -> dict:
        return {
            "frames": self.frames, "used_frames": self.used_frames, "samples": self.samples,
            "unknown_ids": dict(self.unknown_ids), "unknown_frames": sum(self.unknown_ids.values()),
            "wrong_length": dict(self.wrong_length), "undecodable": dict(self.undecodable),
            "other_channel": self.other_channel, "stale": dict(self.stale),
            "counter_mismatch": dict(self.counter_mismatch), "incomplete_samples": self.incomplete_samples,
            "lost_samples": self.lost_samples, "lost_frames": dict(self.lost_frames),
            "lost_by_signal": self.lost_by_signal, "first_loss_time": self.first_loss_time,
            "trigger_frames": self.trigger_frames,
            "channels_seen": {str(k): v for k, v in self.channels_seen.items()},
            "wanted_on_other_channel": {str(k): v for k, v in self.wanted_on_other_channel.items()},
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
        if self.lost_samples or self.lost_frames:
            out.append(self.loss_line())
        return out

    def loss_line(self) -> str:
        """One line: samples and frames lost, from when."""
        since = "" if self.first_loss_time is None else f" from t = {self.first_loss_time:.3f} s"
        frames = ", ".join(f"{k} {v}" for k, v in sorted(self.lost_frames.items())) or "none"
        return (f"{self.lost_samples} sample(s) lost ({100 * self.loss_fraction():.1f} %){since}"
                f" (sample-time and COUNTER gaps); frames lost by message: {frames}")


class FrameAssembler:
    """Feed :class:`can.Message` frames; get samples when the trigger message arrives."""

    def __init__(self, db: cantools.database.can.Database, signal_map: SignalMap, filter_channel: bool = True,
                 channel: str | None = None):
        """``filter_channel``: keep only frames of the map's ``channel`` (or of ``channel`` when given; ``"any"``
        keeps all), compared as :func:`online_id.drivers.channels.normalise_channel` names; a live bus is one
        channel."""
        signal_map.check_against(db)
        self.map = signal_map
        self._channel = channel_option(channel or signal_map.channel) if filter_channel else None
        self.stats = FrameStats()
        self._messages = {}
        for name in signal_map.messages:
            m = db.get_message_by_name(name)
            self._messages[m.frame_id] = m
        self._trigger_id = db.get_message_by_name(signal_map.trigger).frame_id
        # message name -> (arrival time, decoded, triggers seen before it arrived)
        self._latest: dict[str, tuple[float, dict, int]] = {}
        self._period: dict[str, float] = {}  # message name -> running mean of its arrival intervals [s]
        self._triggers = 0
        self.stats.signals = tuple(signal_map.signals)
        self.loss = LossCounter()
        self.stats.lost_frames = self.loss.lost_frames

    def feed(self, msg: can.Message) -> Sample | None:
        st = self.stats
        st.frames += 1
        channel = normalise_channel(msg.channel)
        st.channels_seen[channel] += 1
        if self._channel is not None and channel is not None and channel != self._channel:
            st.other_channel += 1
            if msg.arbitration_id in self._messages:
                st.wanted_on_other_channel[channel] += 1
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
        previous = self._latest.get(spec.name)
        if previous is not None and msg.timestamp > previous[0]:
            interval, period = msg.timestamp - previous[0], self._period.get(spec.name)
            self._period[spec.name] = interval if period is None else period + PERIOD_WEIGHT * (interval - period)
        self._latest[spec.name] = (msg.timestamp, decoded, self._triggers)
        if self.map.counter is not None:
            self.loss.frame(spec.name, decoded.get(self.map.counter))
        if msg.arbitration_id != self._trigger_id:
            return None
        self._triggers += 1
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
            t, decoded, seen = entry
            if now - t > self._stale_after(spec.message):
                st.stale[name] += 1
                continue
            if counter is not None and not self._same_sample(entry, counter):
                st.counter_mismatch[name] += 1
                continue
            values[name] = spec.scale * sum(float(decoded[s]) for s in spec.signals) + spec.offset
        time = now
        if m.time is not None:
            # the sensor's time or none: a bus arrival time in its place would mix two time bases
            t_entry = self._latest.get(m.time[0])
            usable = (t_entry is not None and now - t_entry[0] <= self._stale_after(m.time[0])
                      and (counter is None or self._same_sample(t_entry, counter)))
            time = float(t_entry[1][m.time[1]]) if usable else None
        if time is None or "steering_wheel_angle" not in values or "speed" not in values:
            st.incomplete_samples += 1
            return None
        st.samples += 1
        self.loss.sample(time if m.time is not None else None, counter)
        st.lost_samples, st.first_loss_time = self.loss.lost_samples, self.loss.first_loss_time
        return Sample(time=time, steering_wheel_angle=values["steering_wheel_angle"], speed=values["speed"],
                      yaw_rate=values.get("yaw_rate"), lateral_acceleration=values.get("lateral_acceleration"),
                      roll_angle=values.get("roll_angle"), roll_rate=values.get("roll_rate"),
                      lateral_velocity=values.get("lateral_velocity"),
                      longitudinal_acceleration=values.get("longitudinal_acceleration"))

    def _stale_after(self, message: str) -> float:
        """Age [s] beyond which ``message``'s latest value is stale: the map's, or STALE_PERIODS of its period."""
        return max(self.map.stale_after_s, STALE_PERIODS * self._period.get(message, 0.0))

    def _same_sample(self, entry: tuple[float, dict, int], counter) -> bool:
        """A frame belongs to the sample being assembled: same counter, and it arrived after the
        previous trigger (so a frame is never used twice, however many samples the counter skipped)."""
        _, decoded, seen = entry
        return decoded.get(self.map.counter) == counter and seen >= self._triggers - 1
