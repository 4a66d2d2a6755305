"""The filter's bounded record of its normalised block innovations, read by the consistency verdict
(:mod:`online_id.trust.consistency`)."""

from __future__ import annotations

import numpy as np

from online_id.stream.samples import MEASURED_CHANNELS

N_CHANNELS = len(MEASURED_CHANNELS)

#: Block innovations kept by :class:`InnovationLog` (a ring buffer): 2e5 corrections are 67 min at
#: the default 50 corrections/s, in 2e5 x 10 floats = 16 MB; older ones are forgotten.
INNOVATION_LOG_CAPACITY = 200_000


class InnovationLog:
    """Bounded record of the normalised block innovations of a filter, one row per correction.

    Row: time [s], converged (0/1), ν (4,) = (z - ẑ)/√S_ii per channel (NaN where the block had no
    sample of the channel), and f (4,) = R_used/R_nominal (the adaptive and tempering inflation the
    filter applied to R). ν·√f is the innovation against the nominal sensor noise (exact when R
    dominates S, as it does once the parameters are learned; larger otherwise).
    """

    def __init__(self, capacity: int = INNOVATION_LOG_CAPACITY):
        self.capacity = capacity
        # empty, not filled: the operating system maps a page when a row is first written there, so memory
        # grows by the rows recorded, never copied to grow (issue 40: a live run of hours), and a short run
        # pays nothing for the 16 MB (issue 26: start-up to the first sample). Rows are written whole and
        # rows past ``total`` are never read.
        self._rows = np.empty((capacity, 2 + 2 * N_CHANNELS))
        self._next = 0
        self.total = 0

    def record(self, time: float, channels: np.ndarray, nu: np.ndarray, r_inflation: np.ndarray,
               converged: bool) -> None:
        """One correction's innovations of ``channels`` (indices into MEASURED_CHANNELS)."""
        row = self._rows[self._next]
        row[:] = np.nan
        row[0] = time
        row[1] = converged
        row[2 + channels] = nu
        row[2 + N_CHANNELS + channels] = r_inflation
        self._next = (self._next + 1) % self.capacity
        self.total += 1

    def next_row(self) -> np.ndarray:
        """The row the next correction writes (a view: filters/block_close.py ``book_block`` fills it); then
        :meth:`advance`."""
        return self._rows[self._next]

    def advance(self) -> None:
        """The row :meth:`next_row` gave is written: keep it."""
        self._next = (self._next + 1) % self.capacity
        self.total += 1

    def rows(self) -> np.ndarray:
        """The kept rows in time order, (M, 10): read-only, valid until the next :meth:`record` (a live
        verdict reads them every second: a view, no copy of up to 16 MB each time, until the log has wrapped,
        67 min at the default rate; then one copy in time order); copy to keep them."""
        if self.total <= len(self._rows):
            kept = self._rows[:self.total].view()
        else:
            kept = np.concatenate([self._rows[self._next:], self._rows[:self._next]])
        kept.flags.writeable = False
        return kept

    def __len__(self) -> int:
        return min(self.total, len(self._rows))
