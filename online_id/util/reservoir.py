"""A bounded sample of a stream of numbers, for percentiles over a run of any length (issue 40).

:class:`Reservoir` keeps every value up to its capacity, then a uniform random sample of that size
(Vitter's algorithm R): percentiles of what it keeps estimate the whole stream's, in fixed memory.
"""

from __future__ import annotations

from array import array

import numpy as np

#: Values a :class:`Reservoir` keeps by default: 100,000 (0.8 MB), every sample of 100 s at 1 kHz.
RESERVOIR_SIZE = 100_000
_DRAWS = 4096  # uniform numbers drawn at once: one generator call per value is too slow at 1 kHz


class Reservoir:
    """Every value offered up to ``capacity``, then a uniform sample of ``capacity`` of them (seeded:
    the same stream keeps the same values)."""

    def __init__(self, capacity: int = RESERVOIR_SIZE, seed: int = 0):
        self.capacity = capacity
        self.seen = 0
        self._kept = array("d")
        self._rng = np.random.default_rng(seed)
        self._draws, self._next = np.empty(0), 0

    def append(self, value: float) -> None:
        self.seen += 1
        if len(self._kept) < self.capacity:
            self._kept.append(value)
            return
        if self._next == len(self._draws):
            self._draws, self._next = self._rng.random(_DRAWS), 0
        j = int(self._draws[self._next] * self.seen)
        self._next += 1
        if j < self.capacity:
            self._kept[j] = value

    def __len__(self) -> int:
        """Values kept."""
        return len(self._kept)

    def values(self) -> np.ndarray:
        """The values kept (a copy), (min(seen, capacity),)."""
        return np.array(self._kept, dtype=float)

    def __array__(self, dtype=None, copy=None):
        return self.values() if dtype is None else self.values().astype(dtype)
