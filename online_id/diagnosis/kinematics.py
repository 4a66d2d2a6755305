"""What no effect of the model can explain: the lateral kinematics of a run that logs its lateral velocity.

The accelerometer measures the tyres' force over the mass (a specific force); a lateral velocity sensor (an INS, a
Correvit) follows the whole acceleration. On a level road the two agree, whatever the tyres, the loads or the
steering do:

    v̇_y + V·r − a_y = 0

On a banked road the difference is gravity's lateral component, g·sin(bank); with a sensor error, that error. The
model has no input for it: a tyre law or a sensor effect cannot produce it, and a diagnosis that went as far as the
model goes still leaves it. :func:`lateral_kinematics` measures its slow part (a moving mean over :data:`WINDOW_S`,
where sensor noise averages out and a bank, which changes over tens of metres, stays) and how much of that a term
proportional to a_y, to dV/dt or a constant explains (an accelerometer tilted by the body's roll, an INS turned in
yaw, a bias: effects the diagnosis has). What is left beyond :data:`LIMIT_MPS2` is reported with the diagnosis's
remaining gap (``remaining_gap.lateral_kinematics`` in its JSON; on the held-out run with ``--validate``, else on
the whole run, whose held-out 5 s segments are too short for it; also when ``--channels`` leaves the lateral
velocity out: it reads the data, not the model). On the race log: 0.17-0.18 m/s² left (0-300 s, 300-400 s), the same
shape lap after lap (a banked track: ``benchmarks/race_bank.py``, docs/measured.md), worth about 1 % of the held-out
cost there.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import uniform_filter1d

from online_id.io.tracklog import TrackRun

#: s, the moving mean that takes the slow part (sensor noise averages out; a bank changes over tens of metres).
WINDOW_S = 3.0
#: m/s², the slow part left (not proportional to a_y or dV/dt, not a constant) beyond which the run is said to have
#: an input the model lacks: g·sin(0.6°), ten times what a_y's noise (0.05 m/s²) leaves in a 3 s mean at 25 Hz.
LIMIT_MPS2 = 0.1


def lateral_kinematics(run: TrackRun, span: str = "run") -> dict | None:
    """The slow part of v̇_y + V·r − a_y over ``run`` (module docstring; ``span`` names what the run is, for the
    reader: "held-out run", "whole run"), or None when the run logs no lateral velocity. Keys: ``span``, ``checked``
    (False with a ``reason`` when the run is shorter than two windows or has a value that is not finite: no number
    from garbage), and when checked ``window_s``, ``mean_mps2``, ``slow_rms_mps2`` (about the mean),
    ``left_rms_mps2`` (the RMS of what a_y, dV/dt and a constant leave of the slow part), ``coefficients`` (of a_y
    and dV/dt), ``limit_mps2``, ``beyond`` (left above the limit), ``bank_deg_p95`` (the 95th percentile of what is
    left, as the bank angle whose g·sin would give it). A bank that follows a_y (banked corners) or is constant (a
    cross-slope) is taken by those terms and not told: the kinematics cannot tell it from a tilted or biased
    accelerometer."""
    if run.lateral_velocity is None:
        return None
    t = np.asarray(run.time, dtype=float)
    V = np.asarray(run.speed, dtype=float)
    vy = np.asarray(run.lateral_velocity, dtype=float)
    ay = np.asarray(run.lateral_acceleration, dtype=float)
    r = np.asarray(run.yaw_rate, dtype=float)
    if not all(np.isfinite(x).all() for x in (t, V, vy, ay, r)):
        return {"span": span, "checked": False, "reason": "a value that is not finite"}
    if len(t) < 3 or t[-1] - t[0] < 2 * WINDOW_S:
        return {"span": span, "checked": False, "reason": f"shorter than {2 * WINDOW_S:g} s"}
    _, part, left, coef = slow_parts(t, V, vy, ay, r)
    left_rms = float(np.sqrt(np.mean(left ** 2)))
    return {"span": span, "checked": True, "window_s": WINDOW_S, "mean_mps2": float(part.mean()),
            "slow_rms_mps2": float(part.std()), "left_rms_mps2": left_rms,
            "coefficients": {"lateral_acceleration": float(coef[0]), "speed_derivative": float(coef[1])},
            "limit_mps2": LIMIT_MPS2, "beyond": left_rms > LIMIT_MPS2,
            "bank_deg_p95": float(np.degrees(np.arcsin(min(1.0, np.percentile(np.abs(left), 95) / 9.81))))}


def slow_parts(t, V, vy, ay, r):
    """The slow part of v̇_y + V·r − a_y (a :data:`WINDOW_S` moving mean, full windows only) at its times, what a term
    in a_y, in dV/dt and a constant leave of it, and their coefficients (arrays of one run, finite, in SI units):
    :func:`lateral_kinematics`'s measure, and ``benchmarks/race_bank.py``'s along the lap."""
    residual = np.gradient(vy, t) + V * r - ay
    n = max(3, int(round(WINDOW_S / float(np.median(np.diff(t))))))
    inner = slice(n // 2, len(t) - n // 2)  # (the mean of a full window only)

    def slow(x):
        return uniform_filter1d(x, n, mode="nearest")[inner]

    part = slow(residual)
    X = np.column_stack([slow(ay), slow(np.gradient(V, t)), np.ones_like(part)])
    coef, *_ = np.linalg.lstsq(X, part, rcond=None)
    return t[inner], part, part - X @ coef, coef


def kinematics_of(run: TrackRun, validate: TrackRun | None) -> dict | None:
    """:func:`lateral_kinematics` where the diagnosis reads it: the held-out run with ``validate``, else the whole run
    (its held-out 5 s segments are too short for a 3 s mean)."""
    return lateral_kinematics(validate if validate is not None else run,
                              span="held-out run" if validate is not None else "whole run")


def kinematics_line(entry: dict | None) -> list[str]:
    """The terminal's line for :func:`lateral_kinematics`'s entry (none when there is none)."""
    if not entry:
        return []
    where = entry["span"] + ("" if entry.get("judged", True) else ", lateral_velocity not among the judged channels")
    if not entry["checked"]:
        return [f"v̇_y + V·r − a_y not checked ({where}): {entry['reason']}"]
    head = (f"v̇_y + V·r − a_y ({where}; zero on a level road, g·sin(bank) on a banked one): its slow part"
            f" ({entry['window_s']:g} s) {entry['slow_rms_mps2']:.3g} m/s² RMS; what a_y, dV/dt and a constant"
            f" leave of it, {entry['left_rms_mps2']:.3g} m/s² RMS,")
    if not entry["beyond"]:
        return [f"{head} is within {entry['limit_mps2']:g} m/s²: no input missing"]
    return [f"{head} is beyond {entry['limit_mps2']:g} m/s²: an input no effect of the model can produce (a banked"
            f" road, {entry['bank_deg_p95']:.1f}° at the 95th percentile, or an error of the INS or the"
            f" accelerometer)"]
