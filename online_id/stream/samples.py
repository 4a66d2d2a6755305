"""One timestamped sensor sample in canonical names and SI units: what every source yields.

A track-run CSV, a CAN log and a live CAN bus all produce :class:`Sample`
objects; the online estimator consumes them one at a time.  A measured channel
that is absent (or stale) is ``None``; a NaN in a channel is treated by the
estimator as a missing value and counted.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from online_id.io.tracklog import TrackRun

#: Measured channels, in the model's output order (online_id.model.lateral.OUTPUT_NAMES).
MEASURED_CHANNELS: tuple[str, ...] = ("yaw_rate", "roll_angle", "roll_rate", "lateral_acceleration",
                                      "lateral_velocity")


@dataclass(frozen=True, slots=True)
class Sample:
    """Sensor values at one instant.

    time [s], steering_wheel_angle [rad], speed [m/s], yaw_rate [rad/s],
    lateral_acceleration [m/s²], roll_angle [rad], roll_rate [rad/s], lateral_velocity [m/s];
    longitudinal_acceleration [m/s²] is an input, not a measured channel: what a tyre law whose axle loads move
    with braking and traction reads (``load_transfer``).
    """

    time: float
    steering_wheel_angle: float
    speed: float
    yaw_rate: float | None = None
    lateral_acceleration: float | None = None
    roll_angle: float | None = None
    roll_rate: float | None = None
    lateral_velocity: float | None = None
    longitudinal_acceleration: float | None = None

    def measurements(self) -> tuple[float | None, ...]:
        """Measured values in :data:`MEASURED_CHANNELS` order (None where absent)."""
        return (self.yaw_rate, self.roll_angle, self.roll_rate, self.lateral_acceleration, self.lateral_velocity)


def samples_from_run(run: TrackRun, channels: tuple[str, ...] | None = None) -> Iterator[Sample]:
    """The rows of ``run`` as samples; ``channels`` limits the measured channels used."""
    use = [c for c in MEASURED_CHANNELS if getattr(run, c) is not None and (channels is None or c in channels)]
    if run.longitudinal_acceleration is not None:
        use.append("longitudinal_acceleration")
    cols = {c: getattr(run, c).tolist() for c in use}
    t, dH, V = run.time.tolist(), run.steering_wheel_angle.tolist(), run.speed.tolist()
    for k in range(len(t)):
        yield Sample(t[k], dH[k], V[k], **{c: cols[c][k] for c in use})


@dataclass(frozen=True)
class SampleArrays:
    """A whole run of samples as arrays: what the estimators' array path takes
    (:meth:`online_id.filters.base.OnlineEstimator.update_many`), the same numbers as its samples one by one.

    time, steering_wheel_angle, speed (n,) [SI]; ``values`` (n, 5) the measured channels in
    :data:`MEASURED_CHANNELS` order (NaN a missing value, as in a sample), ``absent`` (n, 5) where a sample
    has no value at all (a :class:`Sample`'s None); ``longitudinal_acceleration`` (n,) [m/s²] or None (not
    logged; NaN where a sample has none).
    """

    time: np.ndarray
    steering_wheel_angle: np.ndarray
    speed: np.ndarray
    values: np.ndarray
    absent: np.ndarray
    longitudinal_acceleration: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.time)

    def __iter__(self) -> Iterator[Sample]:
        """The rows as :class:`Sample` objects (where a consumer wants them one by one)."""
        return (self.sample(k) for k in range(len(self)))

    @classmethod
    def from_run(cls, run: TrackRun, channels=None) -> SampleArrays:
        """The rows of ``run`` (as :func:`samples_from_run`): ``channels`` limits the measured channels used."""
        n = len(run.time)
        values = np.zeros((n, len(MEASURED_CHANNELS)))
        absent = np.ones((n, len(MEASURED_CHANNELS)), dtype=bool)
        for i, c in enumerate(MEASURED_CHANNELS):
            col = getattr(run, c)
            if col is not None and (channels is None or c in channels):
                values[:, i] = col
                absent[:, i] = False
        ax = run.longitudinal_acceleration
        return cls(np.asarray(run.time, dtype=float), np.asarray(run.steering_wheel_angle, dtype=float),
                   np.asarray(run.speed, dtype=float), values, absent,
                   None if ax is None else np.asarray(ax, dtype=float))

    @classmethod
    def from_samples(cls, samples) -> SampleArrays:
        """A sequence of :class:`Sample` as arrays (a None in time, steering or speed reads as NaN)."""
        rows = [(s.time, s.steering_wheel_angle, s.speed) + s.measurements() for s in samples]
        data = np.array([[np.nan if v is None else v for v in r] for r in rows], dtype=float).reshape(
            -1, 3 + len(MEASURED_CHANNELS))
        absent = np.array([[v is None for v in r[3:]] for r in rows], dtype=bool).reshape(
            -1, len(MEASURED_CHANNELS))
        values = np.where(absent, 0.0, data[:, 3:])
        ax = [s.longitudinal_acceleration for s in samples]
        logged = any(a is not None for a in ax)
        return cls(data[:, 0].copy(), data[:, 1].copy(), data[:, 2].copy(), values, absent,
                   np.array([np.nan if a is None else a for a in ax], dtype=float) if logged else None)

    def sample(self, k: int) -> Sample:
        """Row ``k`` as a :class:`Sample`."""
        m = [None if a else float(v) for v, a in zip(self.values[k], self.absent[k])]
        ax = self.longitudinal_acceleration
        return Sample(float(self.time[k]), float(self.steering_wheel_angle[k]), float(self.speed[k]),
                      yaw_rate=m[0], roll_angle=m[1], roll_rate=m[2], lateral_acceleration=m[3], lateral_velocity=m[4],
                      longitudinal_acceleration=None if ax is None else float(ax[k]))


#: The longest a batch block (the fit's and the diagnosis's block means) may span [s]: their default 10
#: samples span 0.1 s on the race-car log (100 Hz) and 10 ms at 1 kHz, both kept; at 10 Hz they would
#: span 1 s, over which a 0.2-4 Hz chirp averages out.
MAX_BATCH_BLOCK_S = 0.1


def block_samples(dt: float, samples: int, max_s: float = MAX_BATCH_BLOCK_S) -> int:
    """Samples per block: ``samples``, fewer when they would span more than ``max_s`` seconds at the sample
    period ``dt`` [s], at least 1."""
    if not dt > 0:
        return max(1, int(samples))
    return max(1, min(int(samples), int(max_s / dt + 1e-6)))
