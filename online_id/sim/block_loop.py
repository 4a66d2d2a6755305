"""The block recursion of :class:`online_id.sim.fast.BlockSimulator` at varying speed, compiled (numba).

x ← Φ(V_m) x + g_m block by block for every parameter set, Φ interpolated linearly between the two grid speeds
around each block's (Φ_lower + a·ΔΦ). In Python this loop was 60 % of the polish's time on the race log (40,000
blocks, nine parameter sets an iteration: 0.28 s a call); compiled, a few ms. Kept in its own module so that
importing the simulator does not import numba (start-up, issue 26).
"""

from __future__ import annotations

import numpy as np

from online_id.util.jit import cached_njit


@cached_njit()
def block_recursion(pair: np.ndarray, lower: np.ndarray, weight: np.ndarray, g: np.ndarray,
                    X_out: np.ndarray) -> None:  # pragma: no cover - compiled
    """X_out[p, m] = x before block m, for x ← (Φ[p, lower[m]] + weight[m]·ΔΦ[p, lower[m]]) x + g[p, m] from x = 0.

    ``pair`` (P, G, 2, S, S): Φ at each grid speed and its step to the next; ``g`` (P, n, S); ``X_out`` (P, n, S)."""
    P, n, S = g.shape
    x = np.zeros(S)
    s0 = np.zeros(S)
    s1 = np.zeros(S)
    for p in range(P):
        x[:] = 0.0
        for m in range(n):
            for r in range(S):
                X_out[p, m, r] = x[r]
            i = lower[m]
            a = weight[m]
            for r in range(S):
                acc0 = 0.0
                acc1 = 0.0
                for c in range(S):
                    acc0 += pair[p, i, 0, r, c] * x[c]
                    acc1 += pair[p, i, 1, r, c] * x[c]
                s0[r] = acc0
                s1[r] = acc1
            for r in range(S):
                x[r] = s0[r] + a * s1[r] + g[p, m, r]
