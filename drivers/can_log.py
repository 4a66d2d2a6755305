"""CAN log files (candump .log, .asc, .blf, .trc, .mf4, .csv, .db: anything python-can's LogReader reads)
as a sample source.

Channels are compared by their normalised names (:mod:`online_id.drivers.channels`), so a map's
``channel = "can0"`` selects the same bus in every format. A log that yields no sample is an error
naming why (no frame, wrong channel with the channels seen, no ID the map uses, no trigger frame,
incomplete samples); a reader that fails (truncated or corrupt file, missing library) is one line
naming the file.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import can
import cantools
from online_id.drivers.assembler import FrameAssembler
from online_id.drivers.base import NoSamplesError, SampleSource
from online_id.drivers.channels import channel_option, normalise_channel
from online_id.drivers.signal_map import SignalMap, SignalMapError

from online_id.errors import OnlineIdError
from online_id.stream.samples import MEASURED_CHANNELS, Sample


class CanLogReadError(OnlineIdError, ValueError):
    """A CAN log the reader could not read (corrupt, truncated, unsupported)."""


def load_dbc(path: str | Path) -> cantools.database.can.Database:
    try:
        return cantools.database.load_file(str(path))
    except FileNotFoundError:
        raise SignalMapError(f"{path}: no such DBC file") from None
    except Exception as exc:  # cantools raises parser-specific errors
        raise SignalMapError(f"{path}: not a readable DBC: {exc}") from None


class CanLogSource(SampleSource):
    """Samples decoded from a CAN log through a DBC and a signal map.

    ``channel``: the CAN channel to use (``can0``, ``1``, ``any``); default: the map's ``channel``.
    """

    def __init__(self, path: str | Path, db, signal_map: SignalMap, channel: str | None = None):
        super().__init__()
        self.path = Path(path)
        if not self.path.exists():
            raise OnlineIdError(f"{self.path}: no such CAN log")
        self.name = str(self.path)
        self.map = signal_map
        self.db = db
        self.channel = channel_option(channel if channel is not None else signal_map.channel)
        self.given_channel = channel  # --can-channel as given (None: the map's)
        self.assembler = FrameAssembler(db, signal_map, channel=channel)
        self._suffix = "".join(s for s in self.path.suffixes[-2:] if s.lower() != ".gz").lower()

    @property
    def channels(self) -> list[str]:
        """Measured channels the map provides, in the model's order."""
        return [c for c in MEASURED_CHANNELS if c in self.map.signals]

    def _samples(self) -> Iterator[Sample]:
        reader = self._open()
        last_time = None
        frames_read = 0
        yielded = 0
        try:
            for msg in reader:
                frames_read += 1
                msg.channel = normalise_channel(msg.channel, self._suffix)
                sample = self.assembler.feed(msg)
                if sample is None:
                    continue
                if last_time is not None and sample.time <= last_time:
                    self.assembler.stats.counter_mismatch["time_not_increasing"] += 1
                    continue
                last_time = sample.time
                yielded += 1
                yield sample
        except (GeneratorExit, KeyboardInterrupt):
            raise
        except Exception as exc:  # each format's reader raises its own types (struct.error, ValueError, ...)
            raise CanLogReadError(f"{self.path}: unreadable after frame {frames_read}:"
                                  f" {type(exc).__name__}: {exc}") from None
        finally:
            stop = getattr(reader, "stop", None)
            if stop:
                try:
                    stop()
                except Exception:  # noqa: S110 - closing a reader that already failed
                    pass
        if yielded == 0:
            raise NoSamplesError(f"{self.path}: no usable sample: {self.why_no_sample()}")

    def _open(self):
        try:
            return can.LogReader(str(self.path))
        except ImportError as exc:
            raise CanLogReadError(f"{self.path}: cannot read {self._suffix} logs: {exc}") from None
        except ValueError as exc:
            raise CanLogReadError(f"{self.path}: not a CAN log python-can can read: {exc}") from None
        except Exception as exc:  # a corrupt header fails in the reader's constructor
            raise CanLogReadError(f"{self.path}: unreadable: {type(exc).__name__}: {exc}") from None

    def why_no_sample(self) -> str:
        """The first reason, in the order frames pass through, that no sample came out."""
        st, m = self.assembler.stats, self.map
        seen = ", ".join(f"{k} ({v:,} frames)" for k, v in sorted(st.channels_seen.items(), key=lambda kv: str(kv[0])))
        chosen = f"--can-channel {self.given_channel}" if self.given_channel is not None else \
            f"the map {m.name}'s channel {self.channel}"
        if st.frames == 0:
            return "the log holds no frame"
        if st.other_channel == st.frames:
            return f"{chosen} matches no frame; the log has {seen}: choose one with --can-channel (or 'any')"
        if st.used_frames == 0 and st.wanted_on_other_channel:
            where = ", ".join(f"{k} ({v:,} frames)" for k, v in st.wanted_on_other_channel.most_common())
            wanted = ", ".join(m.messages)
            return (f"{chosen} has {st.frames - st.other_channel:,} frames but none of the map's messages ({wanted});"
                    f" they are on {where}: --can-channel {st.wanted_on_other_channel.most_common(1)[0][0]}")
        if st.used_frames == 0:
            ids = ", ".join(sorted(st.unknown_ids)[:8])
            wanted = ", ".join(f"{n} (0x{self.db.get_message_by_name(n).frame_id:X})" for n in m.messages)
            bad = sum(st.wrong_length.values()) + sum(st.undecodable.values())
            extra = f"; {bad} frame(s) of known IDs had the wrong length or could not be decoded" if bad else ""
            return (f"no frame with an ID the map {m.name} uses: it wants {wanted}, the log has {ids}"
                    f"{' and more' if len(st.unknown_ids) > 8 else ''} (wrong DBC or map?){extra}")
        if st.trigger_frames == 0:
            return f"no trigger frame {m.trigger}: a sample is complete only when it arrives"
        problems = "; ".join(st.problems())
        return (f"{st.trigger_frames} trigger frame(s) but every sample lacked steering_wheel_angle or speed"
                f" (stale after {m.stale_after_s:g} s, or another counter){': ' + problems if problems else ''}")

    def report(self) -> dict:
        return self.assembler.stats.to_dict()

    def problems(self) -> list[str]:
        return self.assembler.stats.problems()
