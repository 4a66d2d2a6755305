"""A history of rows in bounded memory, evenly thinned as it grows (a live run of hours: issue 40).

:class:`DecimatedRows` keeps every ``stride``-th row offered, in one preallocated array of ``capacity``
rows. When the array is full, every other kept row is dropped and the stride doubles, so the rows kept are
always those whose number (0, 1, 2, ... in the order offered) is a multiple of the stride: evenly spaced
over the whole span, between ``capacity / 2`` and ``capacity`` of them, the first among them. The last row
offered is kept beside them, so the history always reaches the present.
"""

from __future__ import annotations

import numpy as np


class DecimatedRows:
    """At most ``capacity`` (even, ≥ 2) rows of ``width`` floats, evenly thinned, and the last row offered."""

    def __init__(self, capacity: int, width: int):
        if capacity < 2 or capacity % 2:
            raise ValueError("capacity must be even and at least 2")
        self.capacity, self.width = capacity, width
        self._rows = np.empty((capacity, width))
        self._kept = 0  # rows kept in _rows
        self._offered = 0  # rows offered so far
        self.stride = 1  # the kept rows are those offered with a number that is a multiple of this
        self._last = np.full(width, np.nan)

    def add(self, row) -> None:
        """Offer one row (``width`` values)."""
        k = self._offered
        self._offered += 1
        self._last[:] = row
        if k % self.stride:
            return
        if self._kept == self.capacity:  # full: keep every other row, the stride doubles
            half = self.capacity // 2
            self._rows[:half] = self._rows[0:self.capacity:2]
            self._kept = half
            self.stride *= 2
            if k % self.stride:
                return
        self._rows[self._kept] = self._last
        self._kept += 1

    def __len__(self) -> int:
        """Rows :meth:`rows` returns."""
        return self._kept + (self._offered > 0 and (self._offered - 1) % self.stride != 0)

    @property
    def offered(self) -> int:
        return self._offered

    @property
    def last(self) -> np.ndarray | None:
        """The last row offered (a copy), None before any."""
        return self._last.copy() if self._offered else None

    def rows(self) -> np.ndarray:
        """The kept rows in order, then the last row offered where it was not kept: (M, width), a copy."""
        kept = self._rows[:self._kept]
        if self._offered and (self._offered - 1) % self.stride:
            return np.vstack([kept, self._last[None]])
        return kept.copy()
