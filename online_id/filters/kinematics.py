"""A check of the lateral acceleration against the yaw rate that needs no parameter: a_y = V·(β̇ + r).

For any car and any parameters (MODEL.md, the lateral acceleration), over a run of T seconds

    ∫ (a_y − V·r) dt = ∫ V·β̇ dt = [V·β] − ∫ V̇·β dt,

so with the sideslip within ±β_max the mean of a_y − V·r is bounded by
β_max·(|V_start| + |V_end| + ∫|V̇| dt) / T, which shrinks as the run grows. A mean beyond that bound is
not dynamics: it is an offset on the lateral acceleration (road cross-slope, accelerometer mounting) or,
V times over, on the yaw rate; which of the two the balance cannot tell, and ``--offsets`` estimates both.
The filter's innovations cannot show it early: while the parameters are far from the data, its
prediction errors are one-signed for seconds on a clean run too.
"""

from __future__ import annotations

import math

import numpy as np

from online_id.util.jit import cached_njit

#: Largest sideslip at the centre of gravity [rad] a car holds (road cars stay under 0.05 rad; a race car
#: at the limit about 0.1): the bound on what the dynamics can put into the mean of a_y − V·r.
BETA_MAX_RAD = 0.1
#: A car that spins has no bounded sideslip: its V·r far exceeds any a_y its tyres make (a simulated car at
#: μ 0.7 driven with 80° at the wheel: V·r up to 22.6 m/s² against |a_y| under 8.3). Beyond this ratio of the
#: largest |a_y| (plus SPIN_MARGIN_MPS2 for the yaw-rate noise times V) the balance says nothing. The race car
#: at 1.7 g: largest V·r 12.2 against a_y 16.6; an a_y or yaw-rate offset moves either by a fraction of a m/s².
SPIN_RATIO = 1.5
SPIN_MARGIN_MPS2 = 1.0
#: Smallest mean of a_y − V·r worth naming [m/s²]: 1° of road cross-slope (0.17 m/s²) and the 0.3 m/s² slip
#: of issue 30 lie above it, the simulator's 0.05 m/s² noise averages far below.
MIN_OFFSET_MPS2 = 0.1


class KinematicBalance:
    """Running sums of a_y − V·r over a run (see the module docstring); ``add`` per sample, O(1)."""

    def __init__(self) -> None:
        self.integral = 0.0  # ∫ (a_y − V·r) dt [m/s]
        self.duration = 0.0  # ∫ dt [s]
        self.speed_integral = 0.0  # ∫ V dt [m]
        self.speed_variation = 0.0  # ∫ |V̇| dt [m/s]
        self.first_speed: float | None = None
        self.last_speed = 0.0
        self.max_ay = 0.0  # largest |a_y| [m/s²]
        self.max_v_r = 0.0  # largest |V·r| [m/s²]

    def add(self, dt: float, speed: float, yaw_rate: float, lateral_acceleration: float) -> None:
        """One sample: ``dt`` [s] since the previous one, V [m/s], r [rad/s], a_y [m/s²] (finite)."""
        if self.first_speed is None:
            self.first_speed = self.last_speed = speed
        v_r = speed * yaw_rate
        self.integral += (lateral_acceleration - v_r) * dt
        if abs(v_r) > self.max_v_r:
            self.max_v_r = abs(v_r)
        if abs(lateral_acceleration) > self.max_ay:
            self.max_ay = abs(lateral_acceleration)
        self.duration += dt
        self.speed_integral += speed * dt
        self.speed_variation += abs(speed - self.last_speed)
        self.last_speed = speed

    def add_many(self, dt, speed, yaw_rate, lateral_acceleration) -> None:
        """:meth:`add` of each of several samples (arrays, finite), with the same numbers: the running sums
        are accumulated in order."""
        dt, speed = np.asarray(dt, dtype=float), np.asarray(speed, dtype=float)
        if not len(dt):
            return
        if self.first_speed is None:
            self.first_speed = self.last_speed = float(speed[0])
        sums = np.array([self.integral, self.duration, self.speed_integral, self.speed_variation, self.max_v_r,
                         self.max_ay, self.last_speed])
        # (writable contiguous copies whatever the caller's columns: one compile of the loop, not one per layout)
        sums = _running_sums(sums, np.array(dt, dtype=float), np.array(speed, dtype=float),
                             np.array(yaw_rate, dtype=float), np.array(lateral_acceleration, dtype=float))
        (self.integral, self.duration, self.speed_integral, self.speed_variation, self.max_v_r, self.max_ay,
         self.last_speed) = sums.tolist()

    @property
    def mean(self) -> float:
        """Mean of a_y − V·r [m/s²] (NaN before any sample)."""
        return self.integral / self.duration if self.duration > 0 else math.nan

    @property
    def mean_speed(self) -> float:
        return self.speed_integral / self.duration if self.duration > 0 else math.nan

    @property
    def spun(self) -> bool:
        """The car's V·r went far beyond its a_y (a spin): its sideslip was not bounded, nor is the mean."""
        return self.max_v_r > SPIN_RATIO * self.max_ay + SPIN_MARGIN_MPS2

    @property
    def bound(self) -> float:
        """What the dynamics can put into :attr:`mean` [m/s²] (inf before any sample)."""
        if self.duration <= 0 or self.first_speed is None or self.spun:
            return math.inf
        return BETA_MAX_RAD * (abs(self.first_speed) + abs(self.last_speed) + self.speed_variation) / self.duration

    def offset(self, expected: float = 0.0) -> float | None:
        """The mean of a_y − V·r less ``expected`` (what estimated offsets explain: b_ay − V̄·b_r) when it is
        beyond both :attr:`bound` and :data:`MIN_OFFSET_MPS2`, else None."""
        excess = self.mean - expected
        if not math.isfinite(excess) or abs(excess) <= max(self.bound, MIN_OFFSET_MPS2):
            return None
        return excess

    def to_dict(self) -> dict:
        return {"mean_ay_minus_v_r": _rounded(self.mean), "bound": _rounded(self.bound),
                "mean_speed": _rounded(self.mean_speed), "seconds": round(self.duration, 3), "spun": self.spun}


@cached_njit()
def _running_sums(sums, dt, speed, yaw_rate, lateral_acceleration):  # pragma: no cover -- compiled
    """:meth:`KinematicBalance.add` of each sample in order, in one compiled loop (the same numbers: the running
    sums add term by term, the largest values are order-free): ``sums`` (7,) = (∫ (a_y − V·r) dt, ∫ dt, ∫ V dt,
    ∫ |V̇| dt, largest |V·r|, largest |a_y|, the last speed), the samples' arrays (m,)."""
    out = sums.copy()
    for i in range(dt.shape[0]):
        v_r = speed[i] * yaw_rate[i]
        out[0] += (lateral_acceleration[i] - v_r) * dt[i]
        out[1] += dt[i]
        out[2] += speed[i] * dt[i]
        out[3] += abs(speed[i] - out[6])
        out[4] = max(out[4], abs(v_r))
        out[5] = max(out[5], abs(lateral_acceleration[i]))
        out[6] = speed[i]
    return out


def _rounded(x: float) -> float | None:
    return round(float(x), 5) if math.isfinite(x) else None
