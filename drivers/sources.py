"""One way in: any path (or a pandas DataFrame) to samples or to a :class:`~online_id.io.tracklog.TrackRun`.

Every command (``estimate``, ``fit``, ``diagnose``, ``plot convergence``, ``decode``) and the Python
API open their input here. The kind of source is chosen by the file's suffix (:data:`OPENERS`, after
python-can's ``MESSAGE_READERS``), looking inside where a suffix is ambiguous:

=================================  =========================================================
suffix                             source
=================================  =========================================================
``.csv``                           a track-run CSV, or python-can's CAN CSV (by its header)
``.parquet``                       a track-run table (the columns of the track-run CSV)
``.log .asc .blf .trc .db``        a CAN log (python-can), through ``dbc`` and ``signals``
``.mf4``                           raw CAN bus logging (python-can, asammdf), or decoded signals
``.mdf .dat`` (MDF3/MDF4)          decoded signals (:mod:`online_id.drivers.mdf_signals`)
``.gz``                            the same by the inner suffix (CAN logs)
=================================  =========================================================

A CAN log without ``signals`` is read as online-id's own frames (``drivers/data/online_id.dbc``).

From samples to a TrackRun (:func:`run_from_samples`: ``decode``, ``fit``, ``diagnose``): a sample
where a required measured channel (yaw rate, lateral acceleration) is stale or from another counter is
**dropped**, never filled with an old value; an optional channel (roll angle, roll rate) is kept only
when it is present in at least :data:`OPTIONAL_COVERAGE` of the samples (then samples without it are
dropped too), else left out. Every drop is counted in the report; the gaps it leaves are the ones the
sampling report and the fit's even-sampling check then see.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from online_id.drivers.base import NoSamplesError, SampleSource
from online_id.drivers.csv_source import TrackRunSource
from online_id.drivers.signal_map import SignalMap, builtin_dbc_path, load_signal_map

from online_id.errors import LogFormatError, OnlineIdError
from online_id.io.tracklog import (
    DROP_NAN_HINT,
    MAX_MEDIAN_PERIOD_S,
    OPTIONAL_COLUMNS,
    REQUIRED_COLUMNS,
    UNIT_LIMITS,
    TrackRun,
    check_log_path,
    check_time_unit,
    truth_sidecar_path,
)
from online_id.stream.samples import MEASURED_CHANNELS, Sample
from online_id.units import CHANNEL_UNITS
from online_id.util.stages import stage

#: An optional channel (roll) goes into a decoded run only when present in at least this fraction of its
#: samples: a roll channel missing in 1 sample of 100 costs that sample; one missing more often is left out.
OPTIONAL_COVERAGE = 0.99
#: The first line of python-can's CSV log (``can.CSVWriter``).
CAN_CSV_HEADER = "timestamp,arbitration_id"
#: Measured channels a TrackRun requires.
RUN_REQUIRED = tuple(c for c in REQUIRED_COLUMNS if c in MEASURED_CHANNELS)
RUN_OPTIONAL = tuple(c for c in OPTIONAL_COLUMNS if c in MEASURED_CHANNELS)


@dataclass(frozen=True)
class SourceOptions:
    """How to read a source: a DBC path, a signal map (path or built-in name), a CAN channel."""

    dbc: str | Path | None = None
    signals: str | Path | None = None
    can_channel: str | None = None
    #: a table's rows with NaN, inf or empty cells dropped (counted and said), not refused (``--drop-nan``)
    drop_nan: bool = False

    def map_and_db(self):
        """(signal map, cantools database); online-id's own frames when neither is given."""
        from online_id.drivers.can_log import load_dbc

        smap = load_signal_map(self.signals or "online_id")
        if self.dbc is None and self.signals and smap.dbc is None:
            raise OnlineIdError(f"{smap.source} names no DBC: pass --dbc")
        db = load_dbc(self.dbc or smap.dbc or builtin_dbc_path())
        smap.check_against(db)
        return smap, db

    def map_only(self) -> SignalMap | None:
        return load_signal_map(self.signals) if self.signals else None


def _open_csv(path: Path, opts: SourceOptions) -> SampleSource:
    try:
        with path.open(encoding="utf-8-sig", errors="replace") as fh:
            head = fh.readline(len(CAN_CSV_HEADER) + 1).strip().lower()  # bounded: a file may have no line break
    except OSError:
        head = ""  # read_track_run names the problem
    if head.startswith(CAN_CSV_HEADER):
        return _open_can_log(path, opts)
    cmap, note = _column_map(opts, path)
    if cmap is None and not opts.drop_nan:
        try:
            source = TrackRunSource(path)
        except LogFormatError as exc:
            if "missing required column" in str(exc) and cmap is None:
                raise LogFormatError(f"{exc}; a logger's own columns and units are read through a column map:"
                                     " --signals MAP.toml with a [columns] table (docs: the track-run CSV)") from None
            raise
        source.notes += note
        return source
    import pandas as pd

    check_log_path(path, "log")
    try:
        df = pd.read_csv(path, skipinitialspace=True, encoding="utf-8-sig")
    except (ValueError, OSError, UnicodeDecodeError) as exc:  # pandas' ParserError is a ValueError
        raise LogFormatError(f"{path}: not a readable CSV table: {type(exc).__name__}: {exc}") from None
    source = _table_source(df, str(path), cmap, opts)
    source.notes += note
    return source


def _open_parquet(path: Path, opts: SourceOptions) -> SampleSource:
    import pandas as pd

    if not path.exists():
        raise LogFormatError(f"{path}: no such file")
    cmap, note = _column_map(opts, path)
    try:
        df = pd.read_parquet(path)
    except Exception as exc:  # pyarrow raises several types for a bad file
        raise LogFormatError(f"{path}: not a readable parquet table: {type(exc).__name__}: {exc}") from None
    if cmap is None and not opts.drop_nan:
        return TrackRunSource(run=run_from_dataframe(df, str(path)), notes=note)
    source = _table_source(df, str(path), cmap, opts)
    source.notes += note
    return source


def _column_map(opts: SourceOptions, path: Path):
    """(the column map ``--signals`` names for a table, drivers/column_map.py, or None; notes). A CAN signal map
    given for a table (a batch over CAN logs and tables) is not used, and said so, never silently."""
    if opts.signals is None:
        return None, []
    from online_id.drivers.column_map import is_signal_map, load_column_map

    where = _map_path(opts.signals)
    if is_signal_map(where) or not where.is_file() and _shipped(opts.signals, "signals"):
        return None, [f"--signals {opts.signals} is a CAN signal map (DBC signals): not used for this table, whose"
                      " columns are read as the track-run ones (a table takes a column map: a TOML with a [columns]"
                      " table)"]
    return load_column_map(where), []


def _shipped(name, kind: str) -> Path | None:
    """A map shipped in drivers/data (``<name>_<kind>.toml``), or None."""
    from importlib import resources

    p = Path(str(resources.files("online_id.drivers") / "data" / f"{name}_{kind}.toml"))
    return p if p.is_file() else None


def _map_path(signals) -> Path:
    """A column map by path, or by the name of one shipped in drivers/data (``<name>_columns.toml``)."""
    p = Path(signals)
    return p if p.is_file() else (_shipped(signals, "columns") or p)


def _table_source(df, name: str, cmap, opts: SourceOptions) -> TrackRunSource:
    """A table read through a column map and/or with its NaN rows dropped (drivers/column_map.py)."""
    from online_id.drivers.column_map import map_frame

    mapped = map_frame(df, cmap, name, drop_nan=opts.drop_nan)
    if mapped.dropped and len(mapped.frame) < 2:
        raise LogFormatError(f"{name}: {len(mapped.frame)} row(s) left after dropping {mapped.dropped} with NaN,"
                             " inf or empty cells; a run needs at least 2")
    run = run_from_dataframe(mapped.frame, name)
    sidecar = truth_sidecar_path(name)
    if sidecar.exists():
        run = _with_sidecar(run, sidecar)
    return TrackRunSource(run=run, notes=mapped.notes(name), reading=mapped.to_json_dict())


def _with_sidecar(run: TrackRun, sidecar: Path) -> TrackRun:
    import json

    try:
        run.meta = json.loads(sidecar.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise LogFormatError(f"{sidecar}: unreadable truth sidecar: {exc}") from None
    return run


def _open_can_log(path: Path, opts: SourceOptions) -> SampleSource:
    from online_id.drivers.can_log import CanLogSource  # python-can and cantools: only for CAN logs

    smap, db = opts.map_and_db()
    return CanLogSource(path, db, smap, channel=opts.can_channel)


def _open_mdf(path: Path, opts: SourceOptions) -> SampleSource:
    from online_id.drivers.mdf_signals import MdfSignalSource, is_bus_logging, open_mdf

    mdf = open_mdf(path)
    if is_bus_logging(mdf):
        mdf.close()
        if path.suffix.lower() != ".mf4":
            raise OnlineIdError(f"{path}: raw CAN bus logging is read from .mf4 files; rename it")
        return _open_can_log(path, opts)
    return MdfSignalSource(path, opts.map_only(), mdf=mdf)


#: The formats python-can 4 reads (``can.io.player.MESSAGE_READERS``, listed here so that a track-run CSV
#: is opened without importing python-can); a reader plugin's suffix is looked up there when asked for.
CAN_LOG_SUFFIXES = (".asc", ".blf", ".csv", ".db", ".log", ".mf4", ".trc")

#: suffix -> opener(path, options) -> SampleSource.
OPENERS: dict[str, Callable[[Path, SourceOptions], SampleSource]] = {
    **{suffix: _open_can_log for suffix in CAN_LOG_SUFFIXES},
    ".csv": _open_csv,
    ".parquet": _open_parquet,
    ".mf4": _open_mdf,
    ".mdf": _open_mdf,
    ".dat": _open_mdf,
}


@stage("reading the log")
def open_source(path: str | Path, *, dbc=None, signals=None, can_channel=None, drop_nan: bool = False) -> SampleSource:
    """The sample source for ``path`` (see the module docstring). Raises :class:`OnlineIdError`."""
    path = Path(path)
    opts = SourceOptions(dbc, signals, can_channel, drop_nan)
    if path.is_dir() or not path.name:
        check_log_path(path, "log")  # before its (missing) suffix is named as an unknown kind of log
    suffix = path.suffix.lower()
    if suffix == ".gz" and len(path.suffixes) >= 2:
        suffix = path.suffixes[-2].lower()
        if OPENERS.get(suffix) not in (_open_can_log, _open_csv):
            raise OnlineIdError(f"{path}: only CAN logs are read compressed (.log.gz, .asc.gz, ...)")
        return _open_can_log(path, opts)
    opener = OPENERS.get(suffix) or (_open_can_log if _python_can_reads(suffix) else None)
    if opener is None:
        raise OnlineIdError(f"{path}: unknown kind of log {suffix or '(no suffix)'!r}; known:"
                            f" {', '.join(sorted(OPENERS))}")
    check_log_path(path, "log")  # a directory or a device: said as such (the API calls here too)
    if opener is not _open_can_log and opener is not _open_csv and can_channel is not None:
        raise OnlineIdError(f"--can-channel: {path} is not a CAN log")
    return opener(path, opts)


def _python_can_reads(suffix: str) -> bool:
    """True when a python-can reader plugin (entry point ``can.io.message_reader``) reads ``suffix``."""
    from can.io import player

    getattr(player, "_update_reader_plugins", lambda: None)()  # private in python-can 4; plugins only
    return suffix in player.MESSAGE_READERS


def is_track_run(source: SampleSource) -> bool:
    return isinstance(source, TrackRunSource)


# -- channel selection ---------------------------------------------------------------------------------

def select_channels(wanted: str | Iterable[str] | None, source: SampleSource) -> list[str]:
    """The measured channels to use: ``wanted`` (``"yaw_rate,roll_angle"`` or a list), checked against
    what ``source`` provides; all of those when None."""
    available = source.channels
    if wanted is None:
        return list(available)
    names = [c.strip() for c in wanted.split(",")] if isinstance(wanted, str) else [str(c).strip() for c in wanted]
    names = [c for c in names if c]
    if not names:
        raise OnlineIdError("--channels: no channel given")
    for c in names:
        if c not in MEASURED_CHANNELS:
            raise OnlineIdError(f"--channels: unknown channel {c!r}; choose from {', '.join(MEASURED_CHANNELS)}")
        if c not in available:
            raise OnlineIdError(f"--channels: {c} is not in {source.name} (it has {', '.join(available) or 'none'})")
    return names


def only_channels(samples: Iterable[Sample], channels: Iterable[str]) -> Iterator[Sample]:
    """``samples`` with the measured channels outside ``channels`` removed (set to None)."""
    keep = tuple(c for c in MEASURED_CHANNELS if c in set(channels))
    for s in samples:
        yield Sample(s.time, s.steering_wheel_angle, s.speed, **{c: getattr(s, c) for c in keep},
                     longitudinal_acceleration=s.longitudinal_acceleration)  # (an input, not a channel)


def record_source(result, source: SampleSource, channels: list[str]) -> list[str]:
    """After an estimate over ``source``: ``result.channels`` keeps only the channels that had a value in
    some sample (a mapped channel whose frames never came was not used, and the JSON must not claim it),
    ``result.source_report`` gets what the source saw. Returns the warnings to show."""
    never = [c for c in channels if c not in source.channels_present]
    result.channels = [c for c in channels if c in source.channels_present]
    if source.report():
        result.source_report = {"ended_by": source.ended_by, "frames": source.report()}
    if getattr(source, "reading", None):  # a table read through a column map or with rows dropped
        result.source_report = dict(result.source_report or {"ended_by": source.ended_by}, reading=source.reading)
    warnings = list(source.problems())
    if never and result.samples:
        warnings.append(f"channel(s) {', '.join(never)} mapped but in no sample: not used")
    return warnings


# -- samples and tables to a TrackRun --------------------------------------------------------------------

@dataclass
class DecodeReport:
    """What turning samples into a TrackRun kept and dropped."""

    samples: int = 0
    kept: int = 0
    dropped: dict[str, int] = field(default_factory=dict)  # reason -> samples
    left_out_channels: dict[str, str] = field(default_factory=dict)  # channel -> why

    def to_dict(self) -> dict:
        return {"samples": self.samples, "kept": self.kept, "dropped": dict(self.dropped),
                "left_out_channels": dict(self.left_out_channels)}

    def problems(self) -> list[str]:
        out = [f"{n} sample(s) dropped: {why}" for why, n in self.dropped.items() if n]
        out += [f"channel {c} left out: {why}" for c, why in self.left_out_channels.items()]
        return out


def run_from_samples(samples: Iterable[Sample], name: str,
                     channels: Iterable[str] = MEASURED_CHANNELS) -> tuple[TrackRun, DecodeReport]:
    """A TrackRun from ``samples`` (see the module docstring for what is dropped). ``channels``: the
    measured channels the source provides."""
    rows = [(s.time, s.steering_wheel_angle, s.speed, *s.measurements()) for s in samples]
    report = DecodeReport(samples=len(rows))
    channels = set(channels)
    lacking = [c for c in RUN_REQUIRED if c not in channels]
    if lacking:
        raise OnlineIdError(f"{name}: a track run needs {', '.join(RUN_REQUIRED)}; the source does not give"
                            f" {', '.join(lacking)}")
    if not rows:
        raise NoSamplesError(f"{name}: no usable sample")
    cols = ("time", "steering_wheel_angle", "speed", *MEASURED_CHANNELS)
    a = np.array([[np.nan if v is None else v for v in r] for r in rows], dtype=float)
    data = {c: a[:, j] for j, c in enumerate(cols)}
    keep = np.ones(len(a), dtype=bool)
    for c in RUN_REQUIRED:
        missing = ~np.isfinite(data[c]) & keep
        if missing.any():
            report.dropped[f"{c} stale or missing"] = int(missing.sum())
            keep &= ~missing
    optional = []
    for c in RUN_OPTIONAL:
        if c not in channels:
            continue
        present = np.isfinite(data[c]) & keep
        if keep.sum() and present.sum() >= OPTIONAL_COVERAGE * keep.sum():
            optional.append(c)
            if (keep & ~present).any():
                report.dropped[f"{c} stale or missing"] = int((keep & ~present).sum())
            keep &= present
        else:
            share = present.sum() / max(keep.sum(), 1)
            report.left_out_channels[c] = (f"present in {100 * share:.1f} % of the samples, under"
                                           f" {100 * OPTIONAL_COVERAGE:g} %")
    report.kept = int(keep.sum())
    if report.kept < 2:
        raise NoSamplesError(f"{name}: {report.kept} complete sample(s) of {len(a)}: "
                             + ("; ".join(report.problems()) or "a run needs at least 2"))
    run = TrackRun(**{c: data[c][keep] for c in (*REQUIRED_COLUMNS, *optional)}, source=name)
    step = float(np.median(np.diff(run.time)))
    if step > MAX_MEDIAN_PERIOD_S:  # bus time is in seconds: the samples are too sparse, not in another unit
        raise NoSamplesError(f"{name}: the {report.kept} decoded samples are {step:.3g} s apart (median): too sparse"
                             f" for the model (a sample at least every {MAX_MEDIAN_PERIOD_S:g} s); "
                             + ("; ".join(report.problems()) or "the trigger frames are that sparse"))
    for c in (*REQUIRED_COLUMNS, *optional):  # the track-run reader's limits: what decode writes, it reads back
        if c not in UNIT_LIMITS:
            continue
        limit, hint = UNIT_LIMITS[c]
        over = np.flatnonzero(np.abs(getattr(run, c)) > limit)
        if over.size:
            i = int(over[0])
            raise LogFormatError(f"{name}: decoded {c} = {getattr(run, c)[i]:.6g} {CHANNEL_UNITS[c]} at t ="
                                 f" {run.time[i]:.3f} s exceeds the plausible {limit:.3g} {CHANNEL_UNITS[c]} ({hint});"
                                 f" {over.size} such sample(s): a wrong scale in the DBC or the signal map?")
    return run, report


def run_from_dataframe(df, name: str = "<DataFrame>") -> TrackRun:
    """A TrackRun from a pandas DataFrame with the track-run columns (SI units); checked like the CSV:
    required columns, numbers, no NaN/inf, increasing time, plausible magnitudes."""
    missing = [c for c in REQUIRED_COLUMNS if c not in df.columns]
    if missing:
        raise LogFormatError(f"{name}: missing required column(s) {', '.join(missing)};"
                             f" required: {', '.join(REQUIRED_COLUMNS)}")
    if len(df) < 2:
        raise LogFormatError(f"{name}: {len(df)} row(s); a run needs at least 2")
    cols = {}
    for c in (*REQUIRED_COLUMNS, *OPTIONAL_COLUMNS):
        if c not in df.columns:
            continue
        try:
            v = np.asarray(df[c], dtype=float)
        except (TypeError, ValueError):
            raise LogFormatError(f"{name}: column {c!r} is not numeric") from None
        bad = np.flatnonzero(~np.isfinite(v))
        if bad.size:
            raise LogFormatError(f"{name}: row {int(bad[0])}, column {c!r}: NaN or inf; {bad.size} such row(s)"
                                 f"{DROP_NAN_HINT}")
        if c in UNIT_LIMITS:
            limit, hint = UNIT_LIMITS[c]
            over = np.flatnonzero(np.abs(v) > limit)
            if over.size:
                raise LogFormatError(f"{name}: row {int(over[0])}, column {c!r}: {v[over[0]]:.6g} exceeds the"
                                     f" plausible {limit:.3g} ({hint}); {over.size} such row(s)")
        cols[c] = v
    back = np.flatnonzero(np.diff(cols["time"]) <= 0)
    if back.size:
        raise LogFormatError(f"{name}: row {int(back[0]) + 1}, column 'time': time repeats or goes backwards")
    check_time_unit(cols["time"], name)
    return TrackRun(**cols, source=name)


@dataclass
class Loaded:
    """A run read from any source, with what the source and the decoding reported."""

    run: TrackRun
    source: SampleSource
    decode: DecodeReport | None = None

    def problems(self) -> list[str]:
        return self.source.problems() + (self.decode.problems() if self.decode else [])

    def reading_notes(self) -> list[str]:
        """What reading a table did (columns mapped, rows dropped), for a run that was not decoded."""
        return list(getattr(self.source, "notes", []))

    def report(self) -> dict:
        out = {"ended_by": self.source.ended_by, **({"frames": self.source.report()} if self.source.report() else {})}
        if self.decode is not None:
            out["decode"] = self.decode.to_dict()
        return out


@stage("reading the log")
def load_run(path: str | Path, *, dbc=None, signals=None, can_channel=None, drop_nan: bool = False) -> Loaded:
    """Any source as a TrackRun (a track-run table as it is, or through a column map; others decoded by
    :func:`run_from_samples`)."""
    source = open_source(path, dbc=dbc, signals=signals, can_channel=can_channel, drop_nan=drop_nan)
    if isinstance(source, TrackRunSource):
        return Loaded(source.run, source)
    with source:
        run, report = run_from_samples(source, str(path), source.channels)
    return Loaded(run, source, report)


__all__ = ["OPENERS", "Loaded", "SourceOptions", "load_run", "only_channels", "open_source", "record_source",
           "run_from_dataframe", "run_from_samples", "select_channels"]
