"""CAN log files (candump .log, .asc, .blf, ... anything python-can's LogReader reads) as a sample source."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import can
import cantools

from drivers.assembler import FrameAssembler
from drivers.base import SampleSource
from drivers.signal_map import SignalMap, SignalMapError
from online_id.errors import OnlineIdError
from online_id.samples import Sample


def load_dbc(path: str | Path) -> cantools.database.can.Database:
    try:
        return cantools.database.load_file(str(path))
    except FileNotFoundError:
        raise SignalMapError(f"{path}: no such DBC file") from None
    except Exception as exc:  # cantools raises parser-specific errors
        raise SignalMapError(f"{path}: not a readable DBC: {exc}") from None


class CanLogSource(SampleSource):
    """Samples decoded from a CAN log through a DBC and a signal map."""

    def __init__(self, path: str | Path, db, signal_map: SignalMap):
        super().__init__()
        self.path = Path(path)
        if not self.path.exists():
            raise OnlineIdError(f"{self.path}: no such CAN log")
        self.name = str(self.path)
        self.assembler = FrameAssembler(db, signal_map)

    def _samples(self) -> Iterator[Sample]:
        try:
            reader = can.LogReader(str(self.path))
        except ValueError as exc:
            raise OnlineIdError(f"{self.path}: not a CAN log python-can can read: {exc}") from None
        last_time = None
        frames_read = 0
        try:
            for msg in reader:
                frames_read += 1
                sample = self.assembler.feed(msg)
                if sample is None:
                    continue
                if last_time is not None and sample.time <= last_time:
                    self.assembler.stats.counter_mismatch["time_not_increasing"] += 1
                    continue
                last_time = sample.time
                yield sample
        except (ValueError, IndexError) as exc:  # a truncated or malformed line
            raise OnlineIdError(f"{self.path}: unreadable after frame {frames_read}: {exc}") from None
        finally:
            stop = getattr(reader, "stop", None)
            if stop:
                stop()

    def report(self) -> dict:
        return self.assembler.stats.to_dict()

    def problems(self) -> list[str]:
        return self.assembler.stats.problems()
