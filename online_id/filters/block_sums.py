"""Running sums of one correction block: what the block-averaged EKF update needs.

Per output channel c over the block's accepted samples j: the count n_c, Σ z_j, Σ ŷ_j and Σ H_j,
with H_j the sensitivity of sample j's predicted output to the augmented state at the block start.
The update then uses the means z̄ = Σ z / n, ȳ = Σ ŷ / n, H̄ = Σ H / n (filters/base.py, "Block-averaged
corrections").

Most samples have every usable channel accepted under one shared mask; for those only Σ F_x, Σ x,
Σ δ and Σ z are kept (cheap vector sums) and turned into Σ ŷ and Σ H once, by :meth:`BlockSums.fold`,
with the output model they were predicted with: ŷ and H are linear in (x, F_x, δ, 1) (the 1 carries
the extra states' constant terms, output offsets and direct sensitivities).
"""

from __future__ import annotations

import numpy as np


class BlockSums:
    """Σ z, Σ ŷ, Σ H and counts per channel for ``n_out`` channels and an ``n_aug``-long augmented state.

    ``outputs`` objects have ``summed(Σx, Σδ, count)`` and ``sensitivity(F_x, x, δ, count)``
    (:class:`~online_id.filters.local_model.LinearOutputs`).
    """

    def __init__(self, n_out: int, n_aug: int, n_states: int):
        self.n = np.zeros(n_out)
        self.sum_z = np.zeros(n_out)
        self.sum_y = np.zeros(n_out)
        self.sum_H = np.zeros((n_out, n_aug))
        self._n_states = n_states
        self._channels_added = False  # (whether add_channels or fold put counts into n)
        self._clear_pending()

    def _clear_pending(self):
        self._count = 0
        self._mask = self._weight = self._outputs = None
        self._sum_F = np.zeros((self._n_states, self.sum_H.shape[1]))
        self._sum_x = np.zeros(self._n_states)
        self._sum_delta = 0.0

    @property
    def empty(self) -> bool:
        """Whether nothing was summed yet."""
        return not self._count and not self._channels_added

    def add_accepted(self, mask, outputs, count: int, sum_z, sum_F, sum_x, sum_delta: float) -> None:
        """``count`` samples whose every channel in ``mask`` was accepted, predicted with ``outputs``:
        their sums of measurements (n_out,) (channels outside ``mask`` are not read), chained
        Jacobians (6, N), states (6,) and inputs."""
        if self._count and (outputs is not self._outputs
                            or not (mask is self._mask or (mask == self._mask).all())):
            self.fold()
        if not self._count:
            self._mask, self._weight, self._outputs = mask, mask.astype(float), outputs
        self.sum_z += sum_z
        self._count += count
        self._sum_F += sum_F
        self._sum_x += sum_x
        self._sum_delta += sum_delta

    def add_channels(self, accept, values, y, H) -> None:
        """One sample whose accepted channels are ``accept`` (bool, (n_out,)): values, predictions, H."""
        w = accept.astype(float)
        self._channels_added = self._channels_added or bool(accept.any())
        self.sum_z += values * w
        self.sum_y += y * w
        self.sum_H += H * w[:, None]
        self.n += w

    def fold(self) -> None:
        """Turn the pending sums into Σ ŷ, Σ H and counts (before the output model or mask changes)."""
        if self._count:
            w, out = self._weight, self._outputs
            self.sum_H += out.sensitivity(self._sum_F, self._sum_x, self._sum_delta, self._count) * w[:, None]
            self.sum_y += out.summed(self._sum_x, self._sum_delta, self._count) * w
            self.n += self._count * w
            self._channels_added = self._channels_added or bool(w.any())
        self._clear_pending()

    def means(self):
        """(channels with samples, z̄, ȳ, H̄) after :meth:`fold`, or None when no channel has a sample."""
        self.fold()
        counts = self.n.tolist()  # (five numbers: Python's tests on them cost less than numpy's)
        channels = [i for i, c in enumerate(counts) if c > 0]
        if not channels:
            return None
        channels = np.array(channels)
        n = self.n[channels]
        return channels, self.sum_z[channels] / n, self.sum_y[channels] / n, self.sum_H[channels] / n[:, None]
