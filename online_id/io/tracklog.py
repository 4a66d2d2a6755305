"""The track-run log: the CSV every part of online-id reads and writes.

Columns (header required, SI units, ISO 8855 signs; other columns are ignored):

===============================  ======  =========
column                           unit    required
===============================  ======  =========
``time``                         s       yes
``steering_wheel_angle``         rad     yes
``speed``                        m/s     yes
``yaw_rate``                     rad/s   yes
``lateral_acceleration``         m/s²    yes
``roll_angle``                   rad     no
``roll_rate``                    rad/s   no
``lateral_velocity``             m/s     no
``longitudinal_acceleration``    m/s²    no
===============================  ======  =========

:func:`read_track_run` rejects, with a :class:`~online_id.errors.LogFormatError`
naming file, line and column: missing required columns, non-numeric or empty
cells, NaN or inf, time that goes backwards or repeats, and values whose size
says the unit is wrong (for ``longitudinal_acceleration`` also its slope against the speed's change: in g or
with the sign turned, :func:`check_longitudinal_acceleration`).  Uneven sampling and gaps are reported in
:class:`SamplingReport`, not fatal.

A simulated run may carry a sidecar ``<name>.truth.json`` with the parameters
it was made with; :func:`read_track_run` loads it into ``TrackRun.meta``.
"""

from __future__ import annotations

import csv
import json
import math
import re
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from online_id.errors import LogFormatError
from online_id.units import CHANNEL_UNITS

REQUIRED_COLUMNS: tuple[str, ...] = ("time", "steering_wheel_angle", "speed", "yaw_rate", "lateral_acceleration")
#: Optional measured outputs, then optional inputs (a_x: the load-transfer effects' input, issue 38).
OPTIONAL_COLUMNS: tuple[str, ...] = ("roll_angle", "roll_rate", "lateral_velocity", "longitudinal_acceleration")

#: Largest plausible magnitude of each column in SI units, and what a larger value suggests.
UNIT_LIMITS: dict[str, tuple[float, str]] = {
    "steering_wheel_angle": (4 * math.pi, "degrees instead of radians?"),
    "yaw_rate": (3.0, "deg/s instead of rad/s?"),
    "speed": (120.0, "km/h instead of m/s?"),
    "lateral_acceleration": (50.0, "not m/s²?"),
    "roll_angle": (math.pi / 4, "degrees instead of radians?"),
    "roll_rate": (10.0, "deg/s instead of rad/s?"),
    "lateral_velocity": (60.0, "km/h instead of m/s?"),
    "longitudinal_acceleration": (50.0, "not m/s²?"),
}

#: Said after a NaN, inf or empty cell: the way to read the rest of the file.
DROP_NAN_HINT = "; --drop-nan drops such rows (counted and said)"
#: A step longer than this many times the median sample period is a gap.
GAP_FACTOR = 2.5
#: Longest median sample period [s] of a run: the model's fastest modes (tyre relaxation, yaw) are over
#: 1 Hz, and the filter restarts its states after a step of 0.1 s; a longer median step is a time column
#: in another unit (a 100 Hz log in milliseconds has steps of 10).
MAX_MEDIAN_PERIOD_S = 0.5
#: Units a time column is written in by mistake, and their size in seconds.
TIME_UNITS = (("milliseconds", 1e-3), ("microseconds", 1e-6), ("nanoseconds", 1e-9))


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
    longitudinal_acceleration: np.ndarray | None = None
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


def lateral_velocity_at_cg(run: TrackRun, x_m: float) -> TrackRun:
    """``run`` with its lateral velocity moved from a sensor ``x_m`` metres ahead of the centre of gravity to the
    centre of gravity, v_y,cg = v_y,s − x_s·r with the logged yaw rate (a rigid body; issue 38); ``run`` itself
    when it has no lateral velocity or the sensor is at the CG. Said in ``meta["lateral_velocity_moved_m"]``."""
    if run.lateral_velocity is None or x_m == 0.0 or run.meta.get("lateral_velocity_moved_m") is not None:
        return run
    if run.yaw_rate is None:
        raise LogFormatError(f"{run.source}: lateral_velocity from a sensor {x_m:g} m from the centre of gravity"
                             " needs the yaw rate to be moved there, and the log has none")
    moved = replace(run, lateral_velocity=run.lateral_velocity - x_m * run.yaw_rate,
                    meta={**run.meta, "lateral_velocity_moved_m": float(x_m)})
    return moved


def truth_sidecar_path(path: str | Path) -> Path:
    """Where the truth sidecar of a log lives: ``run.csv`` → ``run.truth.json`` (a path without a name,
    ``.`` or ``/``, has none: a name inside it that no log writes)."""
    p = Path(path)
    return p.with_name(p.stem + ".truth.json") if p.name else p / ".truth.json"


def check_log_path(path: str | Path, what: str = "LOG") -> Path:
    """``path`` as a Path when it names a file that exists, else a one-line :class:`LogFormatError` saying
    what it is instead (no such file, a directory, a device or pipe) under the argument's name ``what``."""
    import stat

    p = Path(path)
    try:
        mode = p.stat().st_mode
    except FileNotFoundError:
        raise LogFormatError(f"{what} {p}: no such file") from None
    except OSError as exc:
        raise LogFormatError(f"{what} {p}: cannot read: {exc.strerror}") from None
    if stat.S_ISDIR(mode):
        raise LogFormatError(f"{what} {p}: is a directory, not a log file (give the log files in it, e.g."
                             f" {p / '*.csv'})")
    if not stat.S_ISREG(mode):
        raise LogFormatError(f"{what} {p}: not a regular file (a device, pipe or socket); give a log file")
    return p


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


def read_track_run(path: str | Path, max_line_bytes: int | None = None) -> TrackRun:
    """Read and validate a track-run CSV.  Raises :class:`LogFormatError` on bad input.

    The numbers are parsed by numpy in one pass (:func:`numpy.loadtxt`). Anything the fast parse
    does not accept as it is (a bad cell, a short row, quotes, blank lines, NaN) sends the file
    through :func:`read_track_run_rowwise`, which names the line and column of the problem, so
    every message is the row-by-row reader's. A UTF-8 byte-order mark is skipped. A line longer than
    ``max_line_bytes`` (default :data:`MAX_LINE_BYTES`) or a NUL byte is refused as soon as the scan
    meets it, so memory stays bounded by the line, not by a file without line breaks.
    """
    path = Path(path)
    name = str(path)
    header_line, body_commas, body_lines = _scan(path, name, max_line_bytes)
    header = _parse_header(header_line, name)
    wanted = [c for c in (*REQUIRED_COLUMNS, *OPTIONAL_COLUMNS) if c in header]
    if body_lines < 2 or body_commas != (len(header) - 1) * body_lines or '"' in header_line:
        return read_track_run_rowwise(path, max_line_bytes)  # uneven rows, quotes or blank lines: let it say where
    try:
        data = np.loadtxt(path, delimiter=",", skiprows=1, usecols=[header.index(c) for c in wanted], ndmin=2,
                          dtype=float, comments=None, encoding="utf-8-sig")
    except ValueError:
        return read_track_run_rowwise(path, max_line_bytes)
    if len(data) < 2 or not np.isfinite(data).all():
        return read_track_run_rowwise(path, max_line_bytes)
    return _finish({c: data[:, j] for j, c in enumerate(wanted)}, path, name)


def read_track_run_rowwise(path: str | Path, max_line_bytes: int | None = None) -> TrackRun:
    """The row-by-row reader (one ``float()`` per cell): the reference for :func:`read_track_run`'s
    messages, and what it falls back on to name the line and column of a bad cell. Lines are bounded as
    in :func:`read_track_run`."""
    path = Path(path)
    name = str(path)
    _scan(path, name, max_line_bytes)
    try:
        fh = path.open(newline="", encoding="utf-8-sig")
    except OSError as exc:
        raise LogFormatError(f"{name}: cannot open: {exc.strerror}") from None
    with fh:
        reader = csv.reader(fh)
        try:
            header_line = fh.readline().rstrip("\r\n")
            first_row = fh.readline()
            fh.seek(0)
            next(reader)
        except StopIteration:
            raise LogFormatError(f"{name}: empty file, expected a header line") from None
        except (csv.Error, UnicodeDecodeError) as exc:
            raise LogFormatError(f"{name}: line 1: not a CSV header: {exc}") from None
        header = _parse_header(header_line, name, first_row.encode("utf-8"))
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
                if any(cell.strip() for cell in row[len(header):]):
                    raise LogFormatError(
                        f"{name}: line {line_no}: {len(row)} cells, header has {len(header)}"
                        f"{_decimal_comma_hint(row)}"
                    )
                rows.append([_cell(row[i], name, line_no, c) for i, c in zip(index, wanted)])
        except (csv.Error, UnicodeDecodeError) as exc:
            raise LogFormatError(f"{name}: line {reader.line_num}: unreadable: {exc}") from None
    if len(rows) < 2:
        numbers = sum(1 for h in header if _is_number(h))
        hint = (f": its header line holds {numbers:,} numbers after the column names, so the rows are on it and"
                " the line breaks are missing (one row per line in a CSV)" if not rows and numbers else "")
        raise LogFormatError(f"{name}: {len(rows)} data row(s); a run needs at least 2{hint}")
    data = np.array(rows, dtype=float)
    return _finish({c: data[:, j] for j, c in enumerate(wanted)}, path, name)


#: Byte-order marks of encodings a track-run CSV is not in, and their names.
_FOREIGN_BOMS: dict[bytes, str] = {b"\xff\xfe": "UTF-16 (little-endian)", b"\xfe\xff": "UTF-16 (big-endian)"}
_UTF8_BOM = b"\xef\xbb\xbf"
#: Separators other than the comma that spreadsheets write, by name.
_OTHER_SEPARATORS: dict[str, str] = {";": "semicolons", "\t": "tabs", "|": "vertical bars"}
#: A number written with a decimal comma, e.g. "0,01" or "-12,5".
_DECIMAL_COMMA = re.compile(r"^[+-]?\d+,\d+$")


#: Bytes read at a time when counting a file's commas and lines.
_SCAN_CHUNK_BYTES = 1 << 20
#: The longest line a track-run CSV may have [bytes]: a row of the 8 columns is under 200 bytes and a
#: logger's header with a thousand columns about 30 KiB. A longer line is a file whose line breaks were
#: lost (or not a CSV): a 150 MB file of one line took 29-48 s and 2-7 GB before a misleading
#: "decimal comma?" hint; it is refused at the first MiB.
MAX_LINE_BYTES = 1 << 20


def _scan(path: Path, name: str, max_line_bytes: int | None = None) -> tuple[str, int, int]:
    """The header line (without a UTF-8 BOM), and the commas and lines of the body (for a cheap check
    that every row has the header's cells), read in chunks. Raises on a missing, unreadable or empty
    file, on a header that is not a track run's, and as soon as it meets a NUL byte or a line longer
    than ``max_line_bytes`` (:data:`MAX_LINE_BYTES`): memory is bounded by that, whatever the file."""
    bound = MAX_LINE_BYTES if max_line_bytes is None else int(max_line_bytes)
    _read_bytes(path, name, len(_UTF8_BOM))
    with path.open("rb") as fh:
        head = _bounded_line(fh.readline(bound + 1), bound, name, 1, 0)
        first_row = _bounded_line(fh.readline(bound + 1), bound, name, 2, len(head))
        commas, lines, last = first_row.count(b","), first_row.count(b"\n"), first_row[-1:]
        offset = len(head) + len(first_row)
        running = 0 if first_row.endswith(b"\n") else len(first_row)  # bytes of the line not yet ended
        step = max(1, min(_SCAN_CHUNK_BYTES, bound))  # no whole line inside a chunk can pass the bound
        while chunk := fh.read(step):
            _no_nul(chunk, name, offset)
            newline = chunk.find(b"\n")
            ended = running + (newline if newline >= 0 else len(chunk))
            if ended > bound:
                _too_long(name, 2 + lines, bound)
            if newline >= 0:
                running = len(chunk) - 1 - chunk.rfind(b"\n")
            else:
                running = ended
            commas += chunk.count(b",")
            lines += chunk.count(b"\n")
            last = chunk[-1:]
            offset += len(chunk)
    if head.startswith(_UTF8_BOM):
        head = head[len(_UTF8_BOM):]
    try:
        header_line = head.decode("utf-8").rstrip("\r\n")
    except UnicodeDecodeError as exc:
        raise LogFormatError(f"{name}: line 1: not a CSV header: {exc}") from None
    if not header_line.strip() and not first_row.strip():
        raise LogFormatError(f"{name}: empty file, expected a header line")
    if last not in (b"\n", b""):
        lines += 1  # the last line has no line break
    _parse_header(header_line, name, first_row)
    return header_line, commas, lines


def _bounded_line(line: bytes, bound: int, name: str, line_no: int, offset: int) -> bytes:
    """``line`` (read with a limit of ``bound`` + 1 bytes) when it holds no NUL and ended within the bound."""
    _no_nul(line, name, offset)
    if len(line) > bound and not line.endswith(b"\n"):
        _too_long(name, line_no, bound)
    return line


def _no_nul(data: bytes, name: str, offset: int) -> None:
    at = data.find(b"\0")
    if at >= 0:
        raise LogFormatError(f"{name}: NUL byte at byte {offset + at:,}: a binary file (or UTF-16 without its"
                             " byte-order mark), not a CSV")


def _too_long(name: str, line_no: int, bound: int) -> None:
    raise LogFormatError(f"{name}: line {line_no}: longer than {bound:,} bytes without a line break: the file's"
                         " line breaks are missing (one row per line in a CSV), or it is not a CSV")


def _read_bytes(path: Path, name: str, size: int) -> bytes:
    """The file's first ``size`` bytes; a missing or unreadable file, or one in an encoding a track
    run is not written in, is a :class:`LogFormatError`."""
    if not path.exists():
        raise LogFormatError(f"{name}: no such file")
    try:
        with path.open("rb") as fh:
            raw = fh.read(size)
    except OSError as exc:
        raise LogFormatError(f"{name}: cannot open: {exc.strerror}") from None
    for bom, encoding in _FOREIGN_BOMS.items():
        if raw.startswith(bom):
            raise LogFormatError(f"{name}: line 1: the file is {encoding}; save it as UTF-8 (or ASCII)")
    return raw


def _parse_header(line: str, name: str, first_row: bytes = b"") -> list[str]:
    """The header's column names; checks the required ones are there, once each."""
    try:
        header = [h.strip() for h in next(csv.reader([line]))]
    except (csv.Error, StopIteration) as exc:
        raise LogFormatError(f"{name}: line 1: not a CSV header: {exc}") from None
    missing = [c for c in REQUIRED_COLUMNS if c not in header]
    if missing:
        _check_separator(line, first_row, name)
        raise LogFormatError(
            f"{name}: line 1: missing required column(s) {', '.join(missing)};"
            f" required: {', '.join(REQUIRED_COLUMNS)}"
        )
    for c in set(header):
        if c in CHANNEL_UNITS and header.count(c) > 1:
            raise LogFormatError(f"{name}: line 1: column {c!r} appears more than once")
    return header


def _check_separator(header_line: str, first_row: bytes, name: str) -> None:
    """A header that has the required columns only when split at ';', tab or '|': say so, not
    "missing column" for each of them."""
    for sep, what in _OTHER_SEPARATORS.items():
        if all(c in [h.strip().strip('"') for h in header_line.split(sep)] for c in REQUIRED_COLUMNS):
            row = first_row.decode("utf-8", errors="replace").split(sep)
            commas = " and decimal commas" if any(_DECIMAL_COMMA.match(c.strip()) for c in row) else ""
            raise LogFormatError(
                f"{name}: line 1: the columns are separated by {what}{commas}; a track-run CSV separates"
                " columns by commas and writes numbers with a decimal point (e.g. 0.01,22.5)")


def _decimal_comma_hint(row: list[str]) -> str:
    """For a row with more cells than the header: what probably happened."""
    pairs = [f"{a.strip()},{b.strip()}" for a, b in zip(row, row[1:]) if a.strip().lstrip("+-").isdigit()
             and b.strip().isdigit()]
    if pairs:
        return (f" (decimal commas? '{pairs[0]}' looks like a number split at its decimal comma; a track-run"
                " CSV writes numbers with a decimal point)")
    return " (a column missing from the header, or a decimal comma?)"


def _finish(columns: dict[str, np.ndarray], path: Path, name: str) -> TrackRun:
    """Check time and magnitudes (naming the line only when one fails), load the truth sidecar."""
    line_of = _LineNumbers(path)
    _check_time(columns["time"], name, line_of)
    for c, values in columns.items():
        _check_magnitude(c, values, name, line_of)
    if "longitudinal_acceleration" in columns:
        check_longitudinal_acceleration(columns["time"], columns["speed"], columns["longitudinal_acceleration"], name)
    meta = {}
    sidecar = truth_sidecar_path(path)
    if sidecar.exists():
        try:
            meta = json.loads(sidecar.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise LogFormatError(f"{sidecar}: unreadable truth sidecar: {exc}") from None
    return TrackRun(**columns, source=name, meta=meta)


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _cell(text: str, name: str, line_no: int, column: str) -> float:
    text = text.strip()
    if not text:
        raise LogFormatError(f"{name}: line {line_no}, column {column!r}: empty cell{DROP_NAN_HINT}")
    try:
        value = float(text)
    except ValueError:
        raise LogFormatError(f"{name}: line {line_no}, column {column!r}: {text!r} is not a number") from None
    if not math.isfinite(value):
        raise LogFormatError(f"{name}: line {line_no}, column {column!r}: {text} (NaN or inf) is not allowed"
                             f"{DROP_NAN_HINT}")
    return value


class _LineNumbers:
    """Data-row index → file line number (blank lines are skipped by the reader); the file is read
    again only when an error needs a line number."""

    def __init__(self, path: Path):
        self.path = path
        self._lines: list[int] | None = None

    def __call__(self, i: int) -> int:
        if self._lines is None:
            self._lines = []
            with self.path.open(encoding="utf-8-sig", newline="") as fh:
                next(fh, None)
                for line_no, line in enumerate(fh, start=2):
                    if line.strip(" ,\r\n"):
                        self._lines.append(line_no)
        return self._lines[i] if i < len(self._lines) else i + 2


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
    check_time_unit(time, name)


def check_time_unit(time: np.ndarray, name: str) -> None:
    """Refuse a time column whose median step is over :data:`MAX_MEDIAN_PERIOD_S`, naming the unit it was
    probably written in (a sample period of 0.1 ms to 0.2 s in that unit)."""
    if len(time) < 2:
        return
    step = float(np.median(np.diff(time)))
    if not step > MAX_MEDIAN_PERIOD_S:
        return
    unit = next((u for u, size in TIME_UNITS if 1e-4 <= step * size <= 0.2), None)
    guess = f" — {unit}? ({1 / (step * dict(TIME_UNITS)[unit]):.4g} Hz if so)" if unit else ""
    raise LogFormatError(f"{name}: column 'time': time steps of {step:.6g} (median){guess}; online-id needs"
                         f" seconds, and samples at least every {MAX_MEDIAN_PERIOD_S:g} s")


def _check_magnitude(column: str, values: np.ndarray, name: str, line_of) -> None:
    if column not in UNIT_LIMITS:
        return
    limit, hint = UNIT_LIMITS[column]
    over = np.flatnonzero(np.abs(values) > limit)
    if over.size:
        i = int(over[0])
        raise LogFormatError(
            f"{name}: line {line_of(i)}, column {column!r}: {values[i]:.6g} exceeds the plausible"
            f" {limit:.3g} {CHANNEL_UNITS[column]} ({hint}); {over.size} such row(s)"
        )


#: Window [s] over which a_x and dV/dt are averaged before they are compared (the speed's quantisation and an
#: accelerometer's vibration averaged out; braking and traction phases last seconds).
AX_CHECK_WINDOW_S = 0.5
#: Least spread [m/s²] of the averaged dV/dt, and least correlation, for the comparison to say anything.
AX_CHECK_MIN_SPREAD = 0.3
AX_CHECK_MIN_CORRELATION = 0.7


def longitudinal_acceleration_slope(time, speed, ax) -> tuple[float, float] | None:
    """Least-squares slope of the logged a_x on dV/dt (both averaged over :data:`AX_CHECK_WINDOW_S`) and their
    correlation; None when the speed hardly changes or the two do not move together (nothing to judge by).
    An accelerometer in m/s² along the car's forward axis gives a slope near 1 (a_x = dV/dt − v_y r: the race
    car of realdata/revs_250lm 1.05, r 0.998); in g, near 1/9.81; with the sign turned, near −1."""
    t, V, a = (np.asarray(x, dtype=float) for x in (time, speed, ax))
    if len(t) < 3:
        return None
    dt = float(np.median(np.diff(t)))
    k = max(1, int(round(AX_CHECK_WINDOW_S / dt))) if dt > 0 else 1
    if len(t) < 3 * k:
        return None
    box = np.ones(k) / k
    dv = np.convolve(np.gradient(V, t), box, "valid")
    am = np.convolve(a, box, "valid")
    if np.std(dv) < AX_CHECK_MIN_SPREAD or np.std(am) == 0:
        return None
    corr = float(np.corrcoef(dv, am)[0, 1])
    if abs(corr) < AX_CHECK_MIN_CORRELATION:
        return None
    return float(np.polyfit(dv, am, 1)[0]), corr


def check_longitudinal_acceleration(time, speed, ax, name: str) -> None:
    """Refuse a ``longitudinal_acceleration`` column in g or with its sign turned, judged by its slope against the
    speed's change (:func:`longitudinal_acceleration_slope`): a :class:`LogFormatError` naming file and column."""
    found = longitudinal_acceleration_slope(time, speed, ax)
    if found is None:
        return
    slope, corr = found
    said = f"{name}: column 'longitudinal_acceleration' rises {slope:.3g}× as fast as the speed's change dV/dt" \
           f" (correlation {corr:.2f})"
    if 0.05 < slope < 0.2:
        raise LogFormatError(f"{said}: in g instead of m/s²? (multiply by 9.80665)")
    if -2.0 < slope < -0.5:
        raise LogFormatError(f"{said}: the sign is turned? (ISO 8855: positive forward, when the speed grows)")


def speed_slope(speed, spacing) -> np.ndarray:
    """dV/dt [m/s²] of a speed (n,) [m/s] by central differences (``numpy.gradient``), ``spacing`` the sample
    times (n,) [s] or one period; zero for fewer than two samples and for a constant speed (exactly)."""
    speed = np.asarray(speed, dtype=float)
    if len(speed) < 2 or np.all(speed == speed[0]):
        return np.zeros(len(speed))
    return np.gradient(speed, spacing)


def longitudinal_acceleration_of(run: TrackRun) -> tuple[np.ndarray, str]:
    """The run's longitudinal acceleration [m/s²] and where it came from: the logged column, or, when it is not
    logged, dV/dt from the speed (:func:`speed_slope`; the v_y·r term of a body-fixed accelerometer left out),
    said so in the second value."""
    if run.longitudinal_acceleration is not None:
        return np.asarray(run.longitudinal_acceleration, dtype=float), "logged longitudinal_acceleration"
    if len(run) < 2:
        return np.zeros(len(run)), "dV/dt from the speed (one sample: zero)"
    return speed_slope(run.speed, run.time), "dV/dt from the speed (no longitudinal_acceleration column)"
