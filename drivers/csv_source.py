"""The track-run CSV as a sample source."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

from online_id.drivers.base import SampleSource

from online_id.io.tracklog import TrackRun, lateral_velocity_at_cg, read_track_run
from online_id.stream.samples import MEASURED_CHANNELS, Sample, SampleArrays, samples_from_run


class TrackRunSource(SampleSource):
    """Samples from a track-run CSV (validated by :func:`online_id.io.tracklog.read_track_run`)."""

    def __init__(self, path: str | Path | None = None, run: TrackRun | None = None, notes: list[str] | None = None,
                 reading: dict | None = None):
        super().__init__()
        self.run = run if run is not None else read_track_run(path)
        self.name = str(path) if path is not None else self.run.source
        #: what reading the table did, one line each (columns mapped, rows dropped: drivers/column_map.py)
        self.notes = list(notes or [])
        #: the same as numbers, for the JSON's ``source_report`` (None when the table was read as it is)
        self.reading = reading

    def _samples(self) -> Iterator[Sample]:
        yield from samples_from_run(self.run)

    def move_lateral_velocity(self, x_m: float) -> None:
        """The run's lateral velocity moved to the centre of gravity
        (:func:`~online_id.io.tracklog.lateral_velocity_at_cg`: the whole column, once; the samples and arrays come
        from it)."""
        self.run = lateral_velocity_at_cg(self.run, float(x_m))

    def arrays(self, channels=None) -> SampleArrays:
        """The run as arrays (the estimators' array path), the measured channels limited to ``channels``;
        counted as iterated (:attr:`channels_present`, :attr:`ended_by`), as the samples would be."""
        if len(self.run):
            self.channels_present.update(self.channels)
        self.ended_by = "end of data"
        return SampleArrays.from_run(self.run, channels)

    def __len__(self) -> int:
        return len(self.run)

    @property
    def channels(self) -> list[str]:
        return [c for c in MEASURED_CHANNELS if getattr(self.run, c) is not None]

    def problems(self) -> list[str]:
        return self.notes + self.run.sampling.warnings()
