"""Fast exact simulation of many parameter sets over one run's inputs (batch fit, diagnosis, polish).

:class:`BlockSimulator` returns the *mean of each output over blocks of q samples*. Within a block
the speed is taken constant at the block's mean speed, grouped into speed levels
(:func:`online_id.sim.levels.speed_levels`, relative width 1e-3); for a constant-speed run this
is the zero-order-hold model of :func:`online_id.sim.simulator.propagate` to round-off. On a run
whose speed varies the block-mean speed differs from each sample's by about half the speed change
over a block (a race car: at most 0.5 m/s at 1 g over a 0.1 s block); the test against the
per-sample recursion bounds the effect on the block means.

For a block of q samples at one speed, with x the state at its start and δ_0..δ_{q-1} its inputs,

    x_next = Φ x + Γ δ,   ȳ = H x + K δ,
    Φ = Ad^q,  Γ[:, i] = Ad^(q-1-i) Bd,  H = C Σ_{j<q} Ad^j / q,  K[:, i] = (C Σ_{j<q-1-i} Ad^j Bd + D) / q,

exactly (ȳ the mean of y_j = C x_j + D δ_j over the block). These block maps depend only on the
parameter set and the speed level, so they are built once per level (not per block) for all
parameter sets at once (one batched eigen-decomposition, :func:`online_id.sim.levels.modal_form`).
The recursion then runs at the block rate: over a long stretch at one level (a constant-speed run)
in modal form by :func:`scipy.signal.lfilter` (compiled), elsewhere by a loop over blocks that
carries every parameter set at once.

:meth:`BlockSimulator.block_means` takes one parameter set (8,) or a stack (P, 8); a stack costs
little more than one (the batched finite-difference Jacobians of the fits rely on it).
"""

from __future__ import annotations

from collections import OrderedDict

import numpy as np
from scipy.signal import lfilter

from online_id.model.lateral import N_STATES
from online_id.sim.levels import SPEED_TOLERANCE, level_runs, modal_form, speed_levels
from online_id.vehicle.parameters import KnownParameters

#: Stretches of at least this many blocks at one level run in modal form (lfilter); shorter ones by the
#: block loop (a Python step costs about as much as a few lfilter samples, plus lfilter's set-up).
MODAL_MIN_BLOCKS = 64
#: Parameter sets whose block means are kept (a fit's Jacobian asks for its 9-17 points, then re-reads them).
CACHE_SIZE = 64


def speed_segments(speed: np.ndarray, tolerance: float = 1e-3) -> list[tuple[int, int, float]]:
    """Split indices into (start, stop, speed) stretches where speed stays within a relative tolerance."""
    V = np.asarray(speed, dtype=float)
    segments = []
    start, ref = 0, V[0]
    for k in range(1, len(V)):
        if abs(V[k] - ref) > tolerance * abs(ref):
            segments.append((start, k, float(V[start:k].mean())))
            start, ref = k, V[k]
    segments.append((start, len(V), float(V[start:].mean())))
    return segments


def block_maps(Ad, Bd, C, D, q: int):
    """Φ (..., 6, 6), Γ (..., 6, q), H (..., 4, 6), K (..., 4, q) of q samples at one speed (module docstring).

    Ad (..., 6, 6), Bd (..., 6), C (..., 4, 6), D (..., 4), single input δ.
    """
    power = np.broadcast_to(np.eye(N_STATES), Ad.shape).copy()
    sums = [np.zeros_like(Ad)]  # sums[n] = Σ_{j<n} Ad^j
    powers_b = []  # Ad^j Bd
    for _ in range(q):
        powers_b.append(np.einsum("...ij,...j->...i", power, Bd))
        sums.append(sums[-1] + power)
        power = power @ Ad
    Phi = power
    Gamma = np.stack(powers_b[::-1], axis=-1)  # column i: Ad^(q-1-i) Bd
    H = C @ sums[q] / q
    K = np.stack([np.einsum("...ij,...j->...i", C @ sums[q - 1 - i], Bd) + D for i in range(q)], axis=-1) / q
    return Phi, Gamma, H, K


class BlockSimulator:
    """Block-mean outputs of the model over one run's inputs, for any parameter set(s).

    Parameters
    ----------
    known : vehicle constants
    steering_wheel_angle, speed : inputs, shape (N,) [rad, m/s] (speed may be a scalar)
    dt : sample period [s]
    block : samples per block q (1 gives every sample); trailing samples that do not fill
        a block are dropped (``n_used`` says how many are used)
    speed_tolerance : relative width of a speed level
    """

    def __init__(self, known: KnownParameters, steering_wheel_angle, speed, dt: float, block: int = 1,
                 speed_tolerance: float = SPEED_TOLERANCE):
        if block < 1:
            raise ValueError("block must be at least 1")
        self.known, self.dt, self.q = known, float(dt), int(block)
        dH = np.asarray(steering_wheel_angle, dtype=float)
        V = np.broadcast_to(np.asarray(speed, dtype=float), dH.shape)
        self.n_blocks = len(dH) // self.q
        self.n_used = self.n_blocks * self.q
        self.delta = (dH[: self.n_used] / known.steering_ratio).reshape(self.n_blocks, self.q)
        self.block_speed = V[: self.n_used].reshape(self.n_blocks, self.q).mean(axis=1)
        self.levels, self.level_of_block = speed_levels(self.block_speed, speed_tolerance)
        self.runs = level_runs(self.level_of_block)
        self._blocks_of_level = [np.flatnonzero(self.level_of_block == i) for i in range(len(self.levels))]
        self._cache: OrderedDict[bytes, np.ndarray] = OrderedDict()
        self.simulations = 0  # parameter sets simulated (cache misses)

    def block_means(self, theta) -> np.ndarray:
        """Mean of each output [r, φ, p, a_y] over each block: (n_blocks, 4) for theta (8,),
        (P, n_blocks, 4) for a stack (P, 8)."""
        theta = np.asarray(theta, dtype=float)
        stack = np.atleast_2d(theta)
        keys = [row.tobytes() for row in stack]
        found = {k: self._cache[k] for k in keys if k in self._cache}
        missing = list({k: i for i, k in enumerate(keys) if k not in found}.values())  # one per distinct set
        if missing:
            for i, y in zip(missing, self._simulate(stack[missing])):
                found[keys[i]] = y
        out = np.stack([found[k] for k in keys])
        for k in keys:  # most recently used last; the oldest leave first
            self._cache[k] = found[k]
            self._cache.move_to_end(k)
        while len(self._cache) > CACHE_SIZE:
            self._cache.popitem(last=False)
        return out[0].copy() if theta.ndim == 1 else out

    def prefetch(self, thetas) -> None:
        """Simulate the rows of ``thetas`` (P, 8) together and keep them for the next calls."""
        self.block_means(np.atleast_2d(thetas))

    def _simulate(self, thetas: np.ndarray) -> np.ndarray:
        P, q = len(thetas), self.q
        self.simulations += P
        with np.errstate(all="ignore"):  # unstable candidates give inf/nan, judged by the caller
            form = modal_form(thetas, self.levels, self.known, self.dt)
            Phi, Gamma, H, K = block_maps(form.Ad, form.Bd[..., 0], form.C, form.D[..., 0], q)
            lev = self.level_of_block
            g = np.empty((P, self.n_blocks, N_STATES))  # Γ δ of each block
            out = np.empty((P, self.n_blocks, 4))
            for level, blocks in enumerate(self._blocks_of_level):
                d = self.delta if len(self.levels) == 1 else self.delta[blocks]
                g[:, blocks] = d @ np.swapaxes(Gamma[:, level], 1, 2)
                out[:, blocks] = d @ np.swapaxes(K[:, level], 1, 2)
            X = np.empty((P, self.n_blocks, N_STATES))  # state at each block start
            x = np.zeros((P, N_STATES))
            for a, b, level in self.runs:
                if b - a >= MODAL_MIN_BLOCKS and form.ok[:, level].all():
                    x = self._modal_run(form, level, g[:, a:b], x, X[:, a:b])
                else:
                    for m in range(a, b):
                        X[:, m] = x
                        x = np.einsum("pij,pj->pi", Phi[:, lev[m]], x) + g[:, m]
            for level, blocks in enumerate(self._blocks_of_level):
                x_level = X if len(self.levels) == 1 else X[:, blocks]
                out[:, blocks] += x_level @ np.swapaxes(H[:, level], 1, 2)
        return out

    def _modal_run(self, form, level, g, x, X_out) -> np.ndarray:
        """Block recursion x ← Φ x + g over a stretch at one level, mode by mode (Φ = W μ^q W⁻¹)."""
        q = self.q
        x_end = np.empty_like(x)
        for p in range(len(x)):
            W, Winv, lam_q = form.W[p, level], form.Winv[p, level], form.mu[p, level] ** q
            v = g[p] @ Winv.T
            z0 = Winv @ x[p]
            Z = np.empty(v.shape, dtype=complex)
            z_end = np.empty(N_STATES, dtype=complex)
            for i in range(N_STATES):
                y, _ = lfilter([1.0], [1.0, -lam_q[i]], v[:, i], zi=[lam_q[i] * z0[i]])
                Z[0, i] = z0[i]
                Z[1:, i] = y[:-1]
                z_end[i] = y[-1]
            X_out[p] = (Z @ W.T).real
            x_end[p] = (W @ z_end).real
        return x_end


def simulate_outputs(theta, known: KnownParameters, steering_wheel_angle, speed, dt: float) -> np.ndarray:
    """Noise-free outputs (N, 4) of one parameter set at every sample (block of 1)."""
    return BlockSimulator(known, steering_wheel_angle, speed, dt, block=1).block_means(theta)
