"""The state recursions of the simulators, compiled (numba): block by block (:class:`online_id.sim.block_means.
BlockSimulator`) and sample by sample (:func:`online_id.sim.simulator.propagate`).

- :func:`varying_block_means`: the block means ȳ = H x + K δ with x ← Φ x + Γ δ block by block for every
  parameter set, each map interpolated linearly between the two grid speeds around each block's (Φ_lower + a·ΔΦ).
  In Python the recursion alone was 60 % of the polish's time on the race log (40,000 blocks, nine parameter
  sets an iteration: 0.28 s a call); compiled, a few ms, and with the interpolation of Γ, H and K in the same
  pass (numpy over the blocks of each grid speed before: 0.8 s of the race log's 1.4 s polish) less again.
- :func:`constant_block_means`: at one speed, the block means ȳ = H x + K δ with x ← Φ x + Γ δ in one pass. It
  replaced a modal run through scipy.signal.lfilter (64 ms an evaluation of the built-in run's polish, and 0.3-0.5 s
  to import scipy.signal with scipy.stats under it; issue 26): the built-in run's 12,000 blocks take about 0.4 ms
  a parameter set.
- :func:`sample_recursion`: x ← Ad[j_k] x + Bd[j_k] δ_k and y = C[j_k] x + D[j_k] δ_k sample by sample, the
  matrices of each sample's speed level j_k (one level at constant speed): the built-in run's 60,000 samples in
  about 2 ms instead of 0.1 s of Python.
- :func:`input_recursion`: x ← Ad[j_k] x + Γ[j_k] w_k and y = C[i_k] x + D[i_k] δ_k sample by sample, the step
  driven by the input polynomial w_k (4,) of a steering that is not held (:mod:`online_id.model.intersample`),
  at the step's speed level j_k, the outputs at the sample's own i_k, kept at every ``every``-th sample (a
  simulation finer than its log, :func:`online_id.sim.simulator.propagate`).
- :func:`level_recursion`: x ← Φ[j_m] x + g_m block by block at each block's speed level (the force-law
  simulation's linear sweeps, :mod:`online_id.sim.forces`), where a Python loop over the blocks (varying speed)
  and scipy.signal.lfilter in modal form (long stretches at one level) ran.

Kept in their own module so that importing the simulator does not import numba (start-up, issue 26).
"""

from __future__ import annotations

import numpy as np

from online_id.model.lateral import N_OUTPUTS, N_STATES
from online_id.util.jit import cached_njit

#: The model's states and outputs, compile-time constants of the loops (numba unrolls them: twice as fast as
#: the same loops over sizes read from the arrays).
S = N_STATES
R = N_OUTPUTS


@cached_njit()
def varying_block_means(Phi: np.ndarray, Gamma: np.ndarray, H: np.ndarray, K: np.ndarray, lower: np.ndarray,
                        weight: np.ndarray, delta: np.ndarray, out: np.ndarray) -> None:  # pragma: no cover
    """out[p, m] = H x + K δ_m, for x the state before block m, x ← Φ x + Γ δ_m from x = 0, each map M the
    interpolation (1 − a)·M[p, i] + a·M[p, i+1] between the grid speeds around block m's (i = lower[m], a =
    weight[m]; Φ as Φ[p, i] + a·(Φ[p, i+1] − Φ[p, i])).

    ``Phi`` (P, G, S, S); ``Gamma`` (P, G, S, q); ``H`` (P, G, R, S); ``K`` (P, G, R, q) at each grid speed;
    ``lower`` (n,) int; ``weight`` (n,); ``delta`` (n, q) the inputs of each block; ``out`` (P, n, R)."""
    P, n = out.shape[0], out.shape[1]
    if Phi.shape[2] != S or out.shape[2] != R:
        raise ValueError("varying_block_means: the model's 6 states and 5 outputs")
    q = delta.shape[1]
    x = np.zeros(S)
    s = np.zeros(S)
    for p in range(P):
        x[:] = 0.0
        for m in range(n):
            i = lower[m]
            a = weight[m]
            for r in range(R):
                lo = 0.0
                hi = 0.0
                for c in range(S):
                    lo += H[p, i, r, c] * x[c]
                    hi += H[p, i + 1, r, c] * x[c]
                du_lo = 0.0
                du_hi = 0.0
                for j in range(q):
                    du_lo += K[p, i, r, j] * delta[m, j]
                    du_hi += K[p, i + 1, r, j] * delta[m, j]
                out[p, m, r] = ((1 - a) * du_lo + a * du_hi) + ((1 - a) * lo + a * hi)
            for r in range(S):
                acc0 = 0.0
                acc1 = 0.0
                for c in range(S):
                    acc0 += Phi[p, i, r, c] * x[c]
                    acc1 += (Phi[p, i + 1, r, c] - Phi[p, i, r, c]) * x[c]
                du_lo = 0.0
                du_hi = 0.0
                for j in range(q):
                    du_lo += Gamma[p, i, r, j] * delta[m, j]
                    du_hi += Gamma[p, i + 1, r, j] * delta[m, j]
                s[r] = acc0 + a * acc1 + ((1 - a) * du_lo + a * du_hi)
            for r in range(S):
                x[r] = s[r]


@cached_njit()
def constant_block_means(Phi: np.ndarray, Gamma: np.ndarray, H: np.ndarray, K: np.ndarray, delta: np.ndarray,
                         out: np.ndarray) -> None:  # pragma: no cover - compiled
    """out[p, m] = H[p] x + K[p] δ_m, for x the state before block m, x ← Φ[p] x + Γ[p] δ_m from x = 0.

    ``Phi`` (P, S, S); ``Gamma`` (P, S, q); ``H`` (P, R, S); ``K`` (P, R, q); ``delta`` (n, q) the inputs of each
    block; ``out`` (P, n, R)."""
    P, n = out.shape[0], out.shape[1]
    if Phi.shape[1] != S or out.shape[2] != R:
        raise ValueError("constant_block_means: the model's 6 states and 5 outputs")
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
        raise ValueError("sample_recursion: the model's 6 states and 5 outputs")
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
def input_recursion(Ad: np.ndarray, Gamma: np.ndarray, C: np.ndarray, D: np.ndarray, step_level: np.ndarray,
                    out_level: np.ndarray, w: np.ndarray, u: np.ndarray, every: int, x0: np.ndarray, X_out: np.ndarray,
                    Y_out: np.ndarray) -> None:  # pragma: no cover - compiled
    """For k = 0, every, 2·every, ...: X_out[k // every] = x before sample k and Y_out[k // every] = C[i] x + D[i] u[k]
    (i = out_level[k]); x ← Ad[j] x + Γ[j] w[k] (j = step_level[k]) at every sample from x0.

    ``Ad`` (L, S, S); ``Gamma`` (L, S, 4); ``C`` (L, R, S); ``D`` (L, R); ``step_level``, ``out_level`` (n,) int;
    ``w`` (n, 4) each sample's step input; ``u`` (n,) the input at each sample; ``x0`` (S,); ``X_out`` (m, S);
    ``Y_out`` (m, R) with m = ⌈n / every⌉."""
    n = u.shape[0]
    if X_out.shape[1] != S or Y_out.shape[1] != R:
        raise ValueError("input_recursion: the model's 6 states and 5 outputs")
    x = x0.copy()
    s = np.zeros(S)
    for k in range(n):
        if k % every == 0:
            m = k // every
            i = out_level[k]
            for r in range(S):
                X_out[m, r] = x[r]
            for r in range(R):
                acc = D[i, r] * u[k]
                for c in range(S):
                    acc += C[i, r, c] * x[c]
                Y_out[m, r] = acc
        j = step_level[k]
        for r in range(S):
            acc = Gamma[j, r, 0] * w[k, 0] + Gamma[j, r, 1] * w[k, 1] + Gamma[j, r, 2] * w[k, 2] \
                + Gamma[j, r, 3] * w[k, 3]
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
