"""A decoded run on an even time grid, for the batch fit and the diagnosis (they simulate with one step).

A car's trigger frame arrives with bus jitter (the RAV4's KINEMATICS, nominally every 12 ms, is
logged 0.1-29 ms apart), so its samples are uneven though the sensor is not. :func:`resample_run`
interpolates every column linearly onto ``t0 + k/rate``; it refuses, naming the time, where two
neighbouring samples are further apart than ``max_gap_s`` (no value is invented across a dropout),
and reports how far the grid moved values (the largest interpolation interval).
"""

from __future__ import annotations

import numpy as np

from online_id.errors import OnlineIdError
from online_id.filters.config import RESTART_PERIODS
from online_id.io.tracklog import OPTIONAL_COLUMNS, REQUIRED_COLUMNS, TrackRun

#: Default longest interval interpolated across [s]: the online filter's own dropout limit
#: (FilterConfig.max_gap_s), past which it restarts the model states; like it, never under RESTART_PERIODS
#: of the run's median period.
MAX_GAP_S = 0.1


def resample_run(run: TrackRun, rate_hz: float, max_gap_s: float = MAX_GAP_S) -> tuple[TrackRun, dict]:
    """``run`` on an even grid at ``rate_hz`` [Hz]; returns the run and ``{"rate_hz", "samples_before",
    "samples", "longest_interval_s"}``."""
    if not rate_hz > 0:
        raise OnlineIdError(f"--resample: the rate must be positive, got {rate_hz:g} Hz")
    t = run.time
    dt = np.diff(t)
    if len(t) < 2:
        raise OnlineIdError(f"{run.source}: {len(t)} sample(s), nothing to resample")
    worst = int(np.argmax(dt))
    max_gap_s = max(max_gap_s, RESTART_PERIODS * float(np.median(dt)))  # a 10 Hz run's every step is 0.1 s
    if dt[worst] > max_gap_s:
        raise OnlineIdError(f"{run.source}: no sample for {dt[worst]:.3g} s after t = {t[worst]:.3f} s; resampling"
                            f" would invent values across it (limit {max_gap_s:g} s): cut the run there")
    grid = t[0] + np.arange(int(np.floor((t[-1] - t[0]) * rate_hz + 1e-9)) + 1) / rate_hz
    cols = {c: np.interp(grid, t, getattr(run, c)) for c in (*REQUIRED_COLUMNS[1:], *OPTIONAL_COLUMNS)
            if getattr(run, c) is not None}
    out = TrackRun(time=grid, **cols, source=run.source, meta=dict(run.meta))
    return out, {"rate_hz": float(rate_hz), "samples_before": len(t), "samples": len(grid),
                 "longest_interval_s": float(dt[worst])}
