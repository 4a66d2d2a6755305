"""online-id's own sensor frames (``data/online_id.dbc``): encoding samples for replay."""

from __future__ import annotations

from collections.abc import Iterator

import can
import cantools
from online_id.drivers.signal_map import builtin_dbc_path

from online_id.io.tracklog import TrackRun

#: Frame order within one sample: the trigger (OID_SPEED_TIME) goes last.
FRAME_ORDER = ("OID_STEERING", "OID_YAW_LAT", "OID_ROLL", "OID_SPEED_TIME")


def load_own_dbc() -> cantools.database.can.Database:
    return cantools.database.load_file(str(builtin_dbc_path()))


def frames_from_run(run: TrackRun, db=None) -> Iterator[can.Message]:
    """The run as CAN frames, 3 or 4 per sample (no roll frame without roll data); ``timestamp`` is
    the sample time [s]. Frames of sample k carry COUNTER = k mod 256."""
    db = db or load_own_dbc()
    msgs = {n: db.get_message_by_name(n) for n in FRAME_ORDER}
    has_roll = run.roll_angle is not None
    zeros = [0.0] * len(run)
    roll = run.roll_angle.tolist() if has_roll else zeros
    roll_rate = run.roll_rate.tolist() if run.roll_rate is not None else zeros
    cols = (run.time.tolist(), run.steering_wheel_angle.tolist(), run.speed.tolist(), run.yaw_rate.tolist(),
            run.lateral_acceleration.tolist(), roll, roll_rate)
    for k, (t, dH, V, r, ay, phi, p) in enumerate(zip(*cols)):
        c = k & 0xFF
        payloads = {
            "OID_STEERING": {"STEERING_WHEEL_ANGLE": dH, "COUNTER": c},
            "OID_YAW_LAT": {"YAW_RATE": r, "LATERAL_ACCELERATION": ay, "COUNTER": c},
            "OID_ROLL": {"ROLL_ANGLE": phi, "ROLL_RATE": p, "COUNTER": c},
            "OID_SPEED_TIME": {"SAMPLE_TIME": t % 4294.967295, "SPEED": V, "COUNTER": c},
        }
        for name in FRAME_ORDER:
            if name == "OID_ROLL" and not has_roll:
                continue
            m = msgs[name]
            yield can.Message(timestamp=t, arbitration_id=m.frame_id, is_extended_id=False,
                              data=m.encode(payloads[name], scaling=True, strict=True))
