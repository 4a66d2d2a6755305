"""One interface for every sensor source (after python-can's ``BusABC``: the base does the common
work, a backend implements one hook).

A source yields :class:`online_id.stream.samples.Sample` objects in canonical names and SI units;
renaming and unit conversion happen once, inside the source. It is a context manager, and after
iteration says how it ended (``ended_by``) and what it saw (``report()``).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Iterator
from dataclasses import replace

from online_id.errors import OnlineIdError
from online_id.stream.samples import MEASURED_CHANNELS, Sample
from online_id.util.interrupts import interrupt_inside


class NoSamplesError(OnlineIdError, ValueError):
    """A source that yielded no usable sample; the message says why."""


class SampleSource(ABC):
    """Base of every source. Subclasses implement :meth:`_samples`."""

    #: short description for messages, e.g. the file name or "udp_multicast:239.74.163.2"
    name: str = "source"

    def __init__(self) -> None:
        self.ended_by: str | None = None
        #: measured channels that had a value in at least one sample yielded so far
        self.channels_present: set[str] = set()
        #: the lateral-velocity sensor's position ahead of the centre of gravity [m] (:meth:`move_lateral_velocity`)
        self.lateral_velocity_x_m = 0.0

    def move_lateral_velocity(self, x_m: float) -> None:
        """Yield the lateral velocity at the centre of gravity, moved from a sensor ``x_m`` metres ahead of it with
        each sample's yaw rate, v_y,cg = v_y,s − x_s·r (the vehicle file's ``[sensors] lateral_velocity_x_m``;
        issue 38). A sample with a lateral velocity and no yaw rate then has no lateral velocity."""
        self.lateral_velocity_x_m = float(x_m)

    def __iter__(self) -> Iterator[Sample]:
        seen = self.channels_present
        x_m = self.lateral_velocity_x_m
        try:
            for sample in self._samples():
                if x_m and sample.lateral_velocity is not None:
                    moved = None if sample.yaw_rate is None else sample.lateral_velocity - x_m * sample.yaw_rate
                    sample = replace(sample, lateral_velocity=moved)
                if len(seen) < len(MEASURED_CHANNELS):
                    seen.update(c for c, v in zip(MEASURED_CHANNELS, sample.measurements()) if v is not None)
                yield sample
            if self.ended_by is None:
                self.ended_by = "end of data"
        except (KeyboardInterrupt, SystemError) as exc:
            if interrupt_inside(exc) is None:  # a SystemError not from a signal in compiled code
                raise
            self.ended_by = "interrupted"
            raise

    @abstractmethod
    def _samples(self) -> Iterator[Sample]:
        """Yield samples until the data ends."""

    @property
    def channels(self) -> list[str]:
        """Measured channels (of ``online_id.stream.samples.MEASURED_CHANNELS``) the source can provide."""
        return []

    def report(self) -> dict:
        """What the source saw (frame counts, problems); empty for sources without frames."""
        return {}

    def problems(self) -> list[str]:
        return []

    def close(self) -> None:  # noqa: B027 - optional hook: most sources hold nothing
        """Release what the source holds (files, bus)."""

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()
