"""Column maps: a logger's own CSV or Parquet columns as the track-run columns, in SI units.

A logger names its columns its own way (``t``, ``yawrate_degps``, ``ay_g``) and writes its own units. A column
map is a small TOML file, like the CAN signal maps beside it (``data/example_logger_columns.toml``), passed with
``--signals`` (the flag that names how a log's channels become online-id's)::

    name = "mylogger"

    [columns.time]                       # canonical name (the track-run columns)
    column = "t"                         # the table's column
    unit = "ms"                          # a unit online-id knows (UNITS), or:
    [columns.yaw_rate]
    column = "yawrate_degps"
    unit = "deg/s"
    scale = -1.0                         # canonical = scale · (value in the unit) + offset: a sign, an offset
    [columns.lateral_acceleration]
    column = "ay"
    unit = "g"

Every required track-run column (time, steering wheel angle, speed, yaw rate, lateral acceleration) must be
mapped; roll angle, roll rate and lateral velocity may be. A column the map names that the table lacks is an
error naming both. Unmapped columns are ignored.

``drop_nan`` (``--drop-nan``): rows with a NaN, an infinity or an empty cell in a column used are dropped,
counted and said (:attr:`Mapped.dropped`), instead of refusing the file at the first one.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from online_id.drivers.mdf_signals import UNIT_FACTORS

from online_id.errors import LogFormatError, OnlineIdError
from online_id.io.tracklog import OPTIONAL_COLUMNS, REQUIRED_COLUMNS

#: Units a column may be written in, per canonical column, and the factor to SI (the MDF reader's, and time's).
UNITS: dict[str, dict[str, float]] = {
    **UNIT_FACTORS,
    "time": {"s": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6, "ns": 1e-9},
    "lateral_velocity": {"m/s": 1.0, "km/h": 1 / 3.6, "kph": 1 / 3.6, "mph": 0.44704},
    "longitudinal_acceleration": UNIT_FACTORS["lateral_acceleration"],
}
#: The keys a column's entry may have.
ENTRY_KEYS = {"column", "unit", "scale", "offset"}


class ColumnMapError(OnlineIdError, ValueError):
    """A column map that cannot be read or does not fit the table."""


@dataclass(frozen=True)
class ColumnSpec:
    """One canonical column: the table's ``column``, converted as ``scale · factor(unit) · x + offset``."""

    column: str
    unit: str
    scale: float = 1.0
    offset: float = 0.0

    def convert(self, canonical: str, values: np.ndarray) -> np.ndarray:
        return self.scale * UNITS[canonical][self.unit] * values + self.offset


@dataclass(frozen=True)
class ColumnMap:
    """``columns``: {canonical name: ColumnSpec}; ``source``: where it was read from."""

    name: str
    columns: dict[str, ColumnSpec]
    source: str = ""


@dataclass
class Mapped:
    """A table in the track-run columns (SI), and what reading it did: rows ``dropped`` with NaN or empty cells
    (count, and the first few row numbers, counted from 1 after the header), the ``map`` used."""

    frame: object  # a pandas DataFrame
    dropped: int = 0
    first_dropped: list[int] = field(default_factory=list)
    map: str | None = None

    def notes(self, name: str) -> list[str]:
        """What to say about the reading, one line each (the map used is in :meth:`to_json_dict`)."""
        out = []
        if self.dropped:
            where = ", ".join(str(r) for r in self.first_dropped) + (", ..." if self.dropped > len(self.first_dropped)
                                                                     else "")
            out.append(f"{self.dropped} row(s) with NaN, inf or an empty cell dropped (--drop-nan): data rows {where}")
        return out

    def to_json_dict(self) -> dict:
        return {"rows_dropped_nan": self.dropped, "first_rows_dropped": list(self.first_dropped),
                "column_map": self.map}


def is_signal_map(path) -> bool:
    """True when ``path`` is a CAN signal map (a TOML file with ``[signals]`` and no ``[columns]`` table)."""
    try:
        data = tomllib.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, ValueError, UnicodeDecodeError):
        return False
    return "signals" in data and "columns" not in data


def load_column_map(path: str | Path) -> ColumnMap:
    """Read and check a column map (see the module docstring)."""
    src = str(path)
    try:
        data = tomllib.loads(Path(path).read_text(encoding="utf-8"))
    except (FileNotFoundError, IsADirectoryError):
        raise ColumnMapError(f"{src}: no such column map") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ColumnMapError(f"{src}: cannot read: {exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ColumnMapError(f"{src}: not valid TOML: {exc}") from None
    table = data.get("columns")
    if not isinstance(table, dict):
        what = " (it is a CAN signal map: DBC signals to canonical ones)" if "signals" in data else ""
        raise ColumnMapError(f"{src}: a CSV or Parquet table takes a column map, a TOML with a [columns] table{what}")
    known = (*REQUIRED_COLUMNS, *OPTIONAL_COLUMNS)
    specs = {}
    for name, entry in table.items():
        if name not in known:
            raise ColumnMapError(f"{src}: columns.{name}: unknown column; choose from {', '.join(known)}")
        if not isinstance(entry, dict) or not isinstance(entry.get("column"), str):
            raise ColumnMapError(f"{src}: columns.{name} needs column = \"<the table's column name>\"")
        extra = set(entry) - ENTRY_KEYS
        if extra:
            raise ColumnMapError(f"{src}: columns.{name}: unknown key(s) {', '.join(sorted(extra))};"
                                 f" known: {', '.join(sorted(ENTRY_KEYS))}")
        units = UNITS[name]
        unit = entry.get("unit", next(iter(units)))
        if unit not in units:
            raise ColumnMapError(f"{src}: columns.{name}: unit {unit!r} is not one for {name}"
                                 f" (accepted: {', '.join(units)})")
        scale, offset = entry.get("scale", 1.0), entry.get("offset", 0.0)
        if not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                   for v in (scale, offset)) or scale == 0:
            raise ColumnMapError(f"{src}: columns.{name}: scale must be a non-zero number, offset a number")
        specs[name] = ColumnSpec(entry["column"], unit, float(scale), float(offset))
    missing = [c for c in REQUIRED_COLUMNS if c not in specs]
    if missing:
        raise ColumnMapError(f"{src}: missing required column(s) {', '.join(missing)} in [columns]")
    return ColumnMap(name=str(data.get("name", Path(path).stem)), columns=specs, source=src)


def map_frame(df, cmap: ColumnMap | None, name: str, drop_nan: bool = False) -> Mapped:
    """``df`` (a pandas DataFrame) in the track-run columns and SI units through ``cmap`` (None: its columns are
    the track-run ones already), with the rows holding NaN, inf or empty cells dropped when ``drop_nan``."""
    import pandas as pd

    specs = cmap.columns if cmap is not None else {c: None for c in (*REQUIRED_COLUMNS, *OPTIONAL_COLUMNS)
                                                   if c in df.columns}
    if cmap is not None:
        absent = [f"{c} ({s.column!r})" for c, s in specs.items() if s.column not in df.columns]
        if absent:
            raise ColumnMapError(f"{name}: the column map {cmap.source} names column(s) the table lacks: "
                                 f"{', '.join(absent)}; the table has {', '.join(map(str, df.columns[:12]))}"
                                 + (", ..." if len(df.columns) > 12 else ""))
    out = {}
    for canonical, spec in specs.items():
        raw = df[canonical if spec is None else spec.column]
        values = pd.to_numeric(raw, errors="coerce").to_numpy(dtype=float)
        text = raw.astype(str).str.strip()
        bad = np.isnan(values) & ~raw.isna().to_numpy() & (text != "").to_numpy() & ~text.str.lower().isin(
            ["nan", "inf", "-inf", "+inf", "infinity", "-infinity"]).to_numpy()
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            raise LogFormatError(f"{name}: data row {k + 1}, column {raw.name!r}: {raw.iloc[k]!r} is not a number")
        out[canonical] = values if spec is None else spec.convert(canonical, values)
    frame = pd.DataFrame(out)
    dropped, first = 0, []
    if drop_nan:
        ok = np.isfinite(frame.to_numpy(dtype=float)).all(axis=1)
        if not ok.all():
            rows = np.flatnonzero(~ok)
            dropped, first = int(len(rows)), [int(r) + 1 for r in rows[:5]]
            frame = frame[ok].reset_index(drop=True)
    return Mapped(frame, dropped, first, cmap.source if cmap is not None else None)
