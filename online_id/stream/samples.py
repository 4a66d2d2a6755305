"""One timestamped sensor sample in canonical names and SI units: what every source yields.

A track-run CSV, a CAN log and a live CAN bus all produce :class:`Sample`
objects; the online estimator consumes them one at a time.  A measured channel
that is absent (or stale) is ``None``; a NaN in a channel is treated by the
estimator as a missing value and counted.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

from online_id.io.tracklog import TrackRun

#: Measured channels, in the model's output order (online_id.model.lateral.OUTPUT_NAMES).
MEASURED_CHANNELS: tuple[str, ...] = ("yaw_rate", "roll_angle", "roll_rate", "lateral_acceleration")


@dataclass(frozen=True, slots=True)
class Sample:
    """Sensor values at one instant.

    time [s], steering_wheel_angle [rad], speed [m/s], yaw_rate [rad/s],
    lateral_acceleration [m/s²], roll_angle [rad], roll_rate [rad/s].
    """

    time: float
    steering_wheel_angle: float
    speed: float
    yaw_rate: float | None = None
    lateral_acceleration: float | None = None
    roll_angle: float | None = None
    roll_rate: float | None = None

    def measurements(self) -> tuple[float | None, ...]:
        """Measured values in :data:`MEASURED_CHANNELS` order (None where absent)."""
        return (self.yaw_rate, self.roll_angle, self.roll_rate, self.lateral_acceleration)


def samples_from_run(run: TrackRun, channels: tuple[str, ...] | None = None) -> Iterator[Sample]:
    """The rows of ``run`` as samples; ``channels`` limits the measured channels used."""
    use = [c for c in MEASURED_CHANNELS if getattr(run, c) is not None and (channels is None or c in channels)]
    cols = {c: getattr(run, c).tolist() for c in use}
    t, dH, V = run.time.tolist(), run.steering_wheel_angle.tolist(), run.speed.tolist()
    for k in range(len(t)):
        yield Sample(t[k], dH[k], V[k], **{c: cols[c][k] for c in use})


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
