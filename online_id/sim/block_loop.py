"""The state recursions of the simulators, compiled (numba): block by block (:class:`online_id.sim.fast.
BlockSimulator`) and sample by sample (:func:`online_id.sim.simulator.propagate`).

- :func:`block_recursion`: x ← Φ(V_m) x + g_m block by block for every parameter set, Φ interpolated linearly
  between the two grid speeds around each block's (Φ_lower + a·ΔΦ). In Python this loop was 60 % of the polish's
  time on the race log (40,000 blocks, nine parameter sets an iteration: 0.28 s a call); compiled, a few ms.
- :func:`constant_block_means`: at one speed, the block means ȳ = H x + K δ with x ← Φ x + Γ δ in one pass. It
  replaced a modal run through scipy.signal.lfilter (64 ms an evaluation of the built-in run's polish, and 0.3-0.5 s
  to import scipy.signal with scipy.stats under it; issue 26): the built-in run's 12,000 blocks take about 1 ms a
  parameter set.
- :func:`sample_recursion`: x ← Ad[j_k] x + Bd[j_k] δ_k and y = C[j_k] x + D[j_k] δ_k sample by sample, the
  matrices of each sample's speed level j_k (one level at constant speed): the built-in run's 60,000 samples in
  about 2 ms instead of 0.1 s of Python.
- :func:`level_recursion`: x ← Φ[j_m] x + g_m block by block at each block's speed level (the force-law
  simulation's linear sweeps, :mod:`online_id.sim.forces`), where a Python loop over the blocks (varying speed)
  and scipy.signal.lfilter in modal form (long stretches at one level) ran.

Kept in their own module so that importing the simulator does not import numba (start-up, issue 26).
"""

from __future__ import annotations

import numpy as np

from online_id.model.lateral import N_STATES
from online_id.util.jit import cached_njit

#: The model's states and outputs, compile-time constants of the loops (numba unrolls them: twice as fast as
#: the same loops over sizes read from the arrays).
S = N_STATES
R = 4


@cached_njit()
def block_recursion(pair: np.ndarray, lower: np.ndarray, weight: np.ndarray, g: np.ndarray,
                    X_out: np.ndarray) -> None:  # pragma: no cover - compiled
    """X_out[p, m] = x before block m, for x ← (Φ[p, lower[m]] + weight[m]·ΔΦ[p, lower[m]]) x + g[p, m] from x = 0.

    ``pair`` (P, G, 2, S, S): Φ at each grid speed and its step to the next; ``g`` (P, n, S); ``X_out`` (P, n, S)."""
    P, n = g.shape[0], g.shape[1]
    if g.shape[2] != S or pair.shape[3] != S:
        raise ValueError("block_recursion: the model's 6 states")
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


@cached_njit()
def constant_block_means(Phi: np.ndarray, Gamma: np.ndarray, H: np.ndarray, K: np.ndarray, delta: np.ndarray,
                         out: np.ndarray) -> None:  # pragma: no cover - compiled
    """out[p, m] = H[p] x + K[p] δ_m, for x the state before block m, x ← Φ[p] x + Γ[p] δ_m from x = 0.

    ``Phi`` (P, S, S); ``Gamma`` (P, S, q); ``H`` (P, R, S); ``K`` (P, R, q); ``delta`` (n, q) the inputs of each
    block; ``out`` (P, n, R)."""
    P, n = out.shape[0], out.shape[1]
    if Phi.shape[1] != S or out.shape[2] != R:
        raise ValueError("constant_block_means: the model's 6 states and 4 outputs")
    q = delta.shape[1]
    x = np.zeros(S)
    s = np.zeros(S)
    for p in range(P):
        F, G, Hp, Kp = Phi[p].copy(), Gamma[p].copy(), H[p].copy(), K[p].copy()
        x[:] = 0.0
        for m in range(n):
            for r in range(R):
                acc = 0.0
                for c in range(S):
                    acc += Hp[r, c] * x[c]
                for i in range(q):
                    acc += Kp[r, i] * delta[m, i]
                out[p, m, r] = acc
            for r in range(S):
                acc = 0.0
                for c in range(S):
                    acc += F[r, c] * x[c]
                for i in range(q):
                    acc += G[r, i] * delta[m, i]
                s[r] = acc
            for r in range(S):
                x[r] = s[r]


@cached_njit()
def sample_recursion(Ad: np.ndarray, Bd: np.ndarray, C: np.ndarray, D: np.ndarray, level: np.ndarray, u: np.ndarray,
                     x0: np.ndarray, X_out: np.ndarray, Y_out: np.ndarray) -> None:  # pragma: no cover - compiled
    """X_out[k] = x before sample k and Y_out[k] = C[j] x + D[j] u[k], for x ← Ad[j] x + Bd[j] u[k] from x0, with
    j = level[k].

    ``Ad`` (L, S, S); ``Bd`` (L, S); ``C`` (L, R, S); ``D`` (L, R); ``level`` (n,) int; ``u`` (n,); ``x0`` (S,);
    ``X_out`` (n, S); ``Y_out`` (n, R)."""
    n = X_out.shape[0]
    if X_out.shape[1] != S or Y_out.shape[1] != R:
        raise ValueError("sample_recursion: the model's 6 states and 4 outputs")
    x = x0.copy()
    s = np.zeros(S)
    for k in range(n):
        j = level[k]
        for r in range(S):
            X_out[k, r] = x[r]
        for r in range(R):
            acc = D[j, r] * u[k]
            for c in range(S):
                acc += C[j, r, c] * x[c]
            Y_out[k, r] = acc
        for r in range(S):
            acc = Bd[j, r] * u[k]
            for c in range(S):
                acc += Ad[j, r, c] * x[c]
            s[r] = acc
        for r in range(S):
            x[r] = s[r]


@cached_njit()
def level_recursion(Phi: np.ndarray, level: np.ndarray, g: np.ndarray, X_out: np.ndarray) -> None:  # pragma: no cover
    """X_out[m] = x before block m, for x ← Φ[level[m]] x + g[m] from x = 0 (:mod:`online_id.sim.forces`).

    ``Phi`` (L, S, S) the block transition at each speed level; ``level`` (n,) int; ``g`` (n, S); ``X_out`` (n, S)."""
    n = X_out.shape[0]
    if X_out.shape[1] != S or g.shape[1] != S:
        raise ValueError("level_recursion: the model's 6 states")
    x = np.zeros(S)
    s = np.zeros(S)
    for m in range(n):
        j = level[m]
        for r in range(S):
            X_out[m, r] = x[r]
        for r in range(S):
            acc = g[m, r]
            for c in range(S):
                acc += Phi[j, r, c] * x[c]
            s[r] = acc
        for r in range(S):
            x[r] = s[r]
