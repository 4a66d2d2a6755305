"""Standard gravity and the measured channels' SI units: one table each, which every other module imports.

Imports nothing of the package, so every layer (the model, the filters, the log reader, the sources, the
pages) can take them.
"""

from __future__ import annotations

#: Standard gravity [m/s²] (CGPM 1901, ISO 80000-3): a_y in g, static axle loads, the plausibility limits.
G = 9.80665

#: The SI unit of each column of a track run (the CSV's columns, a source's samples, the filters' channels).
CHANNEL_UNITS: dict[str, str] = {
    "time": "s",
    "steering_wheel_angle": "rad",
    "speed": "m/s",
    "yaw_rate": "rad/s",
    "lateral_acceleration": "m/s²",
    "roll_angle": "rad",
    "roll_rate": "rad/s",
    "lateral_velocity": "m/s",
    "longitudinal_acceleration": "m/s²",
}
