"""Where :func:`~online_id.estimation.run_estimator` puts the estimate's time history, row by row.

A row is (time [s], the 8 parameters [SI], their 1σ [SI], speed [m/s], lateral acceleration [m/s², NaN
where not measured]): :data:`ROW_WIDTH` floats. Two recorders:

- :class:`TraceRows` keeps every row in memory (a file's estimate: the trace is drawn, written and
  reported after the run);
- :class:`StreamedTrace` writes each row to a CSV as it comes (``listen --trace``: a run of hours, issue 40)
  and keeps in memory only an evenly thinned copy (:class:`~online_id.util.decimated.DecimatedRows`) and the
  last row.

The CSV is :meth:`~online_id.estimation.EstimateTrace.write_csv`'s, byte for byte: the header of
:data:`CSV_COLUMNS`, then one line per row in :data:`CSV_FORMAT` (scripts read these columns).
"""

from __future__ import annotations

from typing import TextIO

import numpy as np

from online_id.util.decimated import DecimatedRows
from online_id.vehicle.parameters import PARAMETER_NAMES

N_PARAMETERS = len(PARAMETER_NAMES)
#: A row: time, the 8 values, the 8 σ, speed, lateral acceleration.
ROW_WIDTH = 3 + 2 * N_PARAMETERS
#: The trace CSV's columns: time, then <name>, <name>_std for each of the 8 parameters (SI units).
CSV_COLUMNS = ["time"] + [f"{n}{s}" for n in PARAMETER_NAMES for s in ("", "_std")]
#: The trace CSV's number format.
CSV_FORMAT = "%.9g"
#: Rows :class:`StreamedTrace` gathers before it writes them and flushes the file: a second of a live run
#: at the default 10 ms between rows (what a killed process can lose, never what an ended one does).
STREAM_BLOCK_ROWS = 100
#: Rows of the thinned copy a streamed trace keeps in memory (1.5 MB): the whole run at 5,000-10,000 points.
STREAM_KEEP_ROWS = 10_000
_FIRST_ROWS = 1024  # TraceRows' first allocation; it doubles as rows come


def write_csv_rows(fh: TextIO, time, values, std) -> None:
    """Rows of the trace CSV (no header): ``time`` (M,), ``values`` and ``std`` (M, 8)."""
    data = np.empty((len(time), 1 + 2 * N_PARAMETERS))
    data[:, 0] = time
    data[:, 1::2] = values
    data[:, 2::2] = std
    np.savetxt(fh, data, delimiter=",", fmt=CSV_FORMAT)


def csv_header() -> str:
    return ",".join(CSV_COLUMNS) + "\n"


def _row(time, values, std, speed, lateral_acceleration, row: np.ndarray | None = None) -> np.ndarray:
    """The row's values in ``row`` (a new array when None)."""
    row = np.empty(ROW_WIDTH) if row is None else row
    row[0] = time
    row[1:1 + N_PARAMETERS] = values
    row[1 + N_PARAMETERS:1 + 2 * N_PARAMETERS] = std
    row[-2], row[-1] = speed, lateral_acceleration
    return row


def _rows(time, values, std, speed, lateral_acceleration, rows: np.ndarray) -> None:
    """Rows (M, ROW_WIDTH) in ``rows`` at ``time``, ``speed``, ``lateral_acceleration`` (M,) with one estimate
    ``values``, ``std`` (8,)."""
    rows[:, 0] = time
    rows[:, 1:1 + N_PARAMETERS] = values
    rows[:, 1 + N_PARAMETERS:1 + 2 * N_PARAMETERS] = std
    rows[:, -2], rows[:, -1] = speed, lateral_acceleration


def columns(rows: np.ndarray) -> tuple:
    """(time (M,), values (M, 8), std (M, 8), speed (M,), lateral acceleration (M,)) of rows (M, ROW_WIDTH)."""
    rows = rows.reshape(-1, ROW_WIDTH)
    return (rows[:, 0].copy(), rows[:, 1:1 + N_PARAMETERS].copy(), rows[:, 1 + N_PARAMETERS:-2].copy(),
            rows[:, -2].copy(), rows[:, -1].copy())


class TraceRows:
    """Every row in memory (a growing array)."""

    def __init__(self):
        self._rows = np.empty((_FIRST_ROWS, ROW_WIDTH))
        self._n = 0

    def add(self, time, values, std, speed, lateral_acceleration) -> None:
        if self._n == len(self._rows):
            grown = np.empty((2 * len(self._rows), ROW_WIDTH))
            grown[:self._n] = self._rows
            self._rows = grown
        _row(time, values, std, speed, lateral_acceleration, self._rows[self._n])
        self._n += 1

    def add_many(self, time, values, std, speed, lateral_acceleration) -> None:
        """Rows at ``time`` (M,) with one estimate ``values``, ``std`` (8,) and their ``speed``,
        ``lateral_acceleration`` (M,): what M calls of :meth:`add` give."""
        m = len(time)
        if self._n + m > len(self._rows):
            grown = np.empty((max(2 * len(self._rows), self._n + m), ROW_WIDTH))
            grown[:self._n] = self._rows[:self._n]
            self._rows = grown
        _rows(time, values, std, speed, lateral_acceleration, self._rows[self._n:self._n + m])
        self._n += m

    @property
    def last(self) -> np.ndarray | None:
        """The last row (a copy), None before any."""
        return self._rows[self._n - 1].copy() if self._n else None

    def __len__(self) -> int:
        return self._n

    def rows(self) -> np.ndarray:
        """Every row, (M, ROW_WIDTH)."""
        return self._rows[:self._n].copy()

    def flush(self) -> None:
        """Nothing to write (for the interface :class:`StreamedTrace` shares)."""


class StreamedTrace:
    """Rows written to ``file`` (a text stream: the trace CSV, its header at once) as they come, in blocks of
    :data:`STREAM_BLOCK_ROWS` each followed by a flush; in memory, at most ``keep`` rows evenly thinned and
    the last row. ``file`` None: nothing written (the thinned copy only). The caller owns and closes the
    file, after :meth:`flush` (which writes the rows still gathered)."""

    def __init__(self, file: TextIO | None = None, keep: int = STREAM_KEEP_ROWS):
        self.file = file
        self.written = 0  # rows written to the file
        self._kept = DecimatedRows(keep, ROW_WIDTH)
        self._block = np.empty((STREAM_BLOCK_ROWS, ROW_WIDTH))
        self._pending = 0
        if file is not None:
            file.write(csv_header())

    def add(self, time, values, std, speed, lateral_acceleration) -> None:
        row = _row(time, values, std, speed, lateral_acceleration)
        self._kept.add(row)
        if self.file is None:
            return
        self._block[self._pending] = row
        self._pending += 1
        if self._pending == STREAM_BLOCK_ROWS:
            self.flush()

    def add_many(self, time, values, std, speed, lateral_acceleration) -> None:
        """:meth:`add` of each row at ``time`` (M,) with one estimate (as :meth:`TraceRows.add_many`)."""
        for k in range(len(time)):
            self.add(time[k], values, std, speed[k], lateral_acceleration[k])

    def flush(self) -> None:
        """Write the rows gathered so far and flush the file."""
        if self.file is None:
            return
        if not self._pending:
            self.file.flush()
            return
        block = self._block[:self._pending]
        write_csv_rows(self.file, block[:, 0], block[:, 1:1 + N_PARAMETERS], block[:, 1 + N_PARAMETERS:-2])
        self.written += self._pending
        self._pending = 0
        self.file.flush()

    @property
    def last(self) -> np.ndarray | None:
        return self._kept.last

    def __len__(self) -> int:
        """Rows offered (written or to be written)."""
        return self._kept.offered

    def rows(self) -> np.ndarray:
        """The thinned copy: (M ≤ keep + 1, ROW_WIDTH), the first and last rows among them."""
        return self._kept.rows()
