"""The track-run log: the CSV every part of online-id reads and writes.

Columns (header required, SI units, ISO 8855 signs; other columns are ignored):

=========================  ======  =========
column                     unit    required
=========================  ======  =========
``time``                   s       yes
``steering_wheel_angle``   rad     yes
``speed``                  m/s     yes
``yaw_rate``               rad/s   yes
``lateral_acceleration``   m/s²    yes
``roll_angle``             rad     no
``roll_rate``              rad/s   no
``lateral_velocity``       m/s     no
=========================  ======  =========

:func:`read_track_run` rejects, with a :class:`~online_id.errors.LogFormatError`
naming file, line and column: missing required columns, non-numeric or empty
cells, NaN or inf, time that goes backwards or repeats, and values whose size
says the unit is wrong.  Uneven sampling and gaps are reported in
:class:`SamplingReport`, not fatal.

A simulated run may carry a sidecar ``<name>.truth.json`` with the parameters
it was made with; :func:`read_track_run` loads it into ``TrackRun.meta``.
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from online_id.errors import LogFormatError

REQUIRED_COLUMNS: tuple[str, ...] = ("time", "steering_wheel_angle", "speed", "yaw_rate", "lateral_acceleration")
OPTIONAL_COLUMNS: tuple[str, ...] = ("roll_angle", "roll_rate", "lateral_velocity")
COLUMN_UNITS: dict[str, str] = {
    "time": "s",
    "steering_wheel_angle": "rad",
    "speed": "m/s",
    "yaw_rate": "rad/s",
    "lateral_acceleration": "m/s²",
    "roll_angle": "rad",
    "roll_rate": "rad/s",
    "lateral_velocity": "m/s",
}

#: Largest plausible magnitude of each column in SI units, and what a larger value suggests.
UNIT_LIMITS: dict[str, tuple[float, str]] = {
    "steering_wheel_angle": (4 * math.pi, "degrees instead of radians?"),
    "yaw_rate": (3.0, "deg/s instead of rad/s?"),
    "speed": (120.0, "km/h instead of m/s?"),
    "lateral_acceleration": (50.0, "not m/s²?"),
    "roll_angle": (math.pi / 4, "degrees instead of radians?"),
    "roll_rate": (10.0, "deg/s instead of rad/s?"),
    "lateral_velocity": (60.0, "km/h instead of m/s?"),
}

#: A step longer than this many times the median sample period is a gap.
GAP_FACTOR = 2.5


@dataclass(frozen=True)
class SamplingReport:
    """How evenly a log is sampled.

    Attributes
    ----------
    samples : number of rows
    median_dt_s : median sample period [s]
    jitter_s : standard deviation of the sample period [s]
    gaps : list of (time_s, length_s) for every step over GAP_FACTOR × median
    """

    samples: int
    median_dt_s: float
    jitter_s: float
    gaps: tuple[tuple[float, float], ...] = ()

    @property
    def rate_hz(self) -> float:
        return 1.0 / self.median_dt_s if self.median_dt_s > 0 else float("nan")

    @property
    def uneven(self) -> bool:
        """True when the period varies by more than 1 % of its median."""
        return self.jitter_s > 0.01 * self.median_dt_s

    def warnings(self) -> list[str]:
        out = []
        if self.gaps:
            longest = max(self.gaps, key=lambda g: g[1])
            out.append(
                f"{len(self.gaps)} gap(s) longer than {GAP_FACTOR:g}× the {self.median_dt_s * 1e3:.3g} ms sample"
                f" period; longest {longest[1]:.3g} s at t = {longest[0]:.3f} s"
            )
        if self.uneven:
            out.append(f"uneven sampling: period {self.median_dt_s * 1e3:.3g} ms ± {self.jitter_s * 1e3:.3g} ms")
        return out

    @classmethod
    def from_time(cls, time: np.ndarray) -> SamplingReport:
        if len(time) < 2:
            return cls(samples=len(time), median_dt_s=float("nan"), jitter_s=0.0)
        dt = np.diff(time)
        median = float(np.median(dt))
        gap_idx = np.flatnonzero(dt > GAP_FACTOR * median)
        gaps = tuple((float(time[i]), float(dt[i])) for i in gap_idx)
        normal = dt[dt <= GAP_FACTOR * median]
        return cls(samples=len(time), median_dt_s=median, jitter_s=float(np.std(normal)), gaps=gaps)


@dataclass
class TrackRun:
    """A logged or simulated run as named arrays of shape (N,), SI units.

    Optional channels are ``None`` when absent. ``meta`` holds what a
    simulation recorded (vehicle, truth parameters, protocol, noise, seed).
    """

    time: np.ndarray
    steering_wheel_angle: np.ndarray
    speed: np.ndarray
    yaw_rate: np.ndarray
    lateral_acceleration: np.ndarray
    roll_angle: np.ndarray | None = None
    roll_rate: np.ndarray | None = None
    lateral_velocity: np.ndarray | None = None
    source: str = "<memory>"
    meta: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.time)

    @property
    def channels(self) -> list[str]:
        """Names of the columns present, in log order."""
        return [c for c in (*REQUIRED_COLUMNS, *OPTIONAL_COLUMNS) if getattr(self, c) is not None]

    @property
    def sampling(self) -> SamplingReport:
        return SamplingReport.from_time(self.time)

    @property
    def truth(self) -> dict[str, float] | None:
        """Parameters the run was simulated with, if known (from the sidecar)."""
        return self.meta.get("truth")

    def slice(self, start: int, stop: int) -> TrackRun:
        """Rows ``start:stop`` as a new run (same meta)."""
        kw = {c: (None if getattr(self, c) is None else getattr(self, c)[start:stop])
              for c in (*REQUIRED_COLUMNS, *OPTIONAL_COLUMNS)}
        return TrackRun(**kw, source=self.source, meta=dict(self.meta))


def truth_sidecar_path(path: str | Path) -> Path:
    """Where the truth sidecar of a log lives: ``run.csv`` → ``run.truth.json``."""
    p = Path(path)
    return p.with_name(p.stem + ".truth.json")


def write_track_run(run: TrackRun, path: str | Path) -> Path:
    """Write ``run`` as a track-run CSV (and its ``meta`` as the truth sidecar when non-empty)."""
    path = Path(path)
    columns = run.channels
    data = np.column_stack([getattr(run, c) for c in columns])
    with path.open("w", newline="", encoding="utf-8") as fh:
        fh.write(",".join(columns) + "\n")
        np.savetxt(fh, data, delimiter=",", fmt="%.10g")
    if run.meta:
        truth_sidecar_path(path).write_text(json.dumps(run.meta, indent=2) + "\n", encoding="utf-8")
    return path


def read_track_run(path: str | Path) -> TrackRun:
    """Read and validate a track-run CSV.  Raises :class:`LogFormatError` on bad input."""
    path = Path(path)
    name = str(path)
    if not path.exists():
        raise LogFormatError(f"{name}: no such file")
    try:
        fh = path.open(newline="", encoding="utf-8")
    except OSError as exc:
        raise LogFormatError(f"{name}: cannot open: {exc.strerror}") from None
    with fh:
        reader = csv.reader(fh)
        try:
            header = next(reader)
        except StopIteration:
            raise LogFormatError(f"{name}: empty file, expected a header line") from None
        except (csv.Error, UnicodeDecodeError) as exc:
            raise LogFormatError(f"{name}: line 1: not a CSV header: {exc}") from None
        header = [h.strip() for h in header]
        missing = [c for c in REQUIRED_COLUMNS if c not in header]
        if missing:
            raise LogFormatError(
                f"{name}: line 1: missing required column(s) {', '.join(missing)};"
                f" required: {', '.join(REQUIRED_COLUMNS)}"
            )
        for c in set(header):
            if c in COLUMN_UNITS and header.count(c) > 1:
                raise LogFormatError(f"{name}: line 1: column {c!r} appears more than once")
        wanted = [c for c in (*REQUIRED_COLUMNS, *OPTIONAL_COLUMNS) if c in header]
        index = [header.index(c) for c in wanted]
        rows: list[list[float]] = []
        try:
            for line_no, row in enumerate(reader, start=2):
                if not row or all(not cell.strip() for cell in row):
                    continue
                if len(row) < len(header):
                    raise LogFormatError(
                        f"{name}: line {line_no}: {len(row)} cells, header has {len(header)}"
                        " (truncated file or row?)"
                    )
                rows.append([_cell(row[i], name, line_no, c) for i, c in zip(index, wanted)])
        except (csv.Error, UnicodeDecodeError) as exc:
            raise LogFormatError(f"{name}: line {reader.line_num}: unreadable: {exc}") from None
    if len(rows) < 2:
        raise LogFormatError(f"{name}: {len(rows)} data row(s); a run needs at least 2")
    data = np.array(rows, dtype=float)
    columns = {c: data[:, j] for j, c in enumerate(wanted)}
    line_of = _line_numbers(path)
    _check_time(columns["time"], name, line_of)
    for c, values in columns.items():
        _check_magnitude(c, values, name, line_of)
    meta = {}
    sidecar = truth_sidecar_path(path)
    if sidecar.exists():
        try:
            meta = json.loads(sidecar.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise LogFormatError(f"{sidecar}: unreadable truth sidecar: {exc}") from None
    return TrackRun(**columns, source=name, meta=meta)


def _cell(text: str, name: str, line_no: int, column: str) -> float:
    text = text.strip()
    if not text:
        raise LogFormatError(f"{name}: line {line_no}, column {column!r}: empty cell")
    try:
        value = float(text)
    except ValueError:
        raise LogFormatError(f"{name}: line {line_no}, column {column!r}: {text!r} is not a number") from None
    if not math.isfinite(value):
        raise LogFormatError(f"{name}: line {line_no}, column {column!r}: {text} (NaN or inf) is not allowed")
    return value


def _line_numbers(path: Path):
    """Map from data-row index to file line number (blank lines are skipped by the reader)."""
    lines = []
    with path.open(encoding="utf-8", newline="") as fh:
        next(fh, None)
        for line_no, line in enumerate(fh, start=2):
            if line.strip(" ,\r\n"):
                lines.append(line_no)
    return lambda i: lines[i] if i < len(lines) else i + 2


def _check_time(time: np.ndarray, name: str, line_of) -> None:
    dt = np.diff(time)
    bad = np.flatnonzero(dt <= 0)
    if bad.size:
        i = int(bad[0]) + 1
        what = "repeats" if dt[i - 1] == 0 else "goes backwards"
        raise LogFormatError(
            f"{name}: line {line_of(i)}, column 'time': time {what}"
            f" ({time[i - 1]:.6g} s then {time[i]:.6g} s); {bad.size} such row(s) in the file"
        )


def _check_magnitude(column: str, values: np.ndarray, name: str, line_of) -> None:
    if column not in UNIT_LIMITS:
        return
    limit, hint = UNIT_LIMITS[column]
    over = np.flatnonzero(np.abs(values) > limit)
    if over.size:
        i = int(over[0])
        raise LogFormatError(
            f"{name}: line {line_of(i)}, column {column!r}: {values[i]:.6g} exceeds the plausible"
            f" {limit:.3g} {COLUMN_UNITS[column]} ({hint}); {over.size} such row(s)"
        )
