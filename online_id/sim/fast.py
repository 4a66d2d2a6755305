"""Fast exact simulation of many parameter sets over one run's inputs (batch fit, diagnosis).

Over a stretch of constant speed the discretised model is linear time-invariant,
x[k+1] = Ad x[k] + Bd δ[k], y = C x + D δ. Diagonalising Ad = W Λ W⁻¹ gives six
independent first-order recursions z_i[k+1] = λ_i z_i[k] + b_i δ[k] (b = W⁻¹Bd),
run by :func:`scipy.signal.lfilter` in compiled code; y = Re(C W z) + D δ. This
is the zero-order-hold model of :func:`online_id.sim.simulator.propagate` to
round-off.

:class:`BlockSimulator` returns the *mean of each output over blocks of q samples*,
still exactly: within a block x_j = λ^j z + Σ_{i<j} λ^{j-1-i} b δ_i, so the block
mean and the next block's start state are linear in the block's q inputs with
weights that are powers of λ. The recursion then runs at the block rate (q times
fewer steps). Comparing block means of model and measurement keeps nearly all the
information of a slowly varying signal and introduces no bias.

Speed is taken piecewise constant (blocks whose speed stays within a relative
tolerance form a segment); the state is carried across segments. A parameter set
whose eigenvectors are ill-conditioned (near-defective Ad) falls back to the
plain recursion.
"""

from __future__ import annotations

import numpy as np
from scipy.signal import lfilter

from online_id.model.discretise import discretise_continuous
from online_id.model.lateral import N_STATES, continuous_matrices, outputs_from_continuous
from online_id.vehicle.parameters import KnownParameters

#: Eigenvector condition number above which the modal form is not trusted.
MAX_MODAL_CONDITION = 1e8


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


class BlockSimulator:
    """Block-mean outputs of the model over one run's inputs, for any parameter set.

    Parameters
    ----------
    known : vehicle constants
    steering_wheel_angle, speed : inputs, shape (N,) [rad, m/s]
    dt : sample period [s]
    block : samples per block q (1 gives every sample); trailing samples that do not fill
        a block are dropped (``n_used`` says how many are used)
    """

    def __init__(self, known: KnownParameters, steering_wheel_angle, speed, dt: float, block: int = 1,
                 speed_tolerance: float = 1e-3):
        if block < 1:
            raise ValueError("block must be at least 1")
        self.known, self.dt, self.q = known, float(dt), int(block)
        dH = np.asarray(steering_wheel_angle, dtype=float)
        V = np.broadcast_to(np.asarray(speed, dtype=float), dH.shape)
        self.n_blocks = len(dH) // self.q
        self.n_used = self.n_blocks * self.q
        self.delta = (dH[: self.n_used] / known.steering_ratio).reshape(self.n_blocks, self.q)
        self.delta_mean = self.delta.mean(axis=1)
        self.segments = speed_segments(V[: self.n_used: self.q], speed_tolerance)
        self.speeds = np.array([s[2] for s in self.segments])
        self._j = np.arange(self.q)

    def block_means(self, theta) -> np.ndarray:
        """Mean of each output [r, φ, p, a_y] over each block, shape (n_blocks, 4)."""
        theta = np.asarray(theta, dtype=float)
        Ac, Bc = continuous_matrices(theta, self.speeds, self.known)
        Ad, Bd = discretise_continuous(Ac, Bc, self.dt)
        C, D = outputs_from_continuous(Ac, Bc, self.speeds)
        out = np.empty((self.n_blocks, 4))
        x = np.zeros(N_STATES, dtype=complex)
        for s, (a, b, _) in enumerate(self.segments):
            x = self._segment(Ad[s], Bd[s], C[s], D[s], self.delta[a:b], self.delta_mean[a:b], x, out[a:b])
        return out

    def _segment(self, Ad, Bd, C, D, delta, delta_mean, x, out):
        q = self.q
        lam, W = np.linalg.eig(Ad)
        if np.linalg.cond(W) >= MAX_MODAL_CONDITION:
            return self._plain(Ad, Bd, C, D, delta, x, out)
        Winv = np.linalg.inv(W)
        b = Winv @ Bd
        z0 = Winv @ x
        powers = lam[None, :] ** np.arange(q + 1)[:, None]  # (q+1, 6): λ^0 .. λ^q
        update_w = powers[q - 1 - self._j]  # (q, 6): λ^(q-1-i)
        # block-mean weights: v_i = (1/q) Σ_{j=i+1}^{q-1} λ^(j-1-i) = (1/q) (1 - λ^(q-1-i)) / (1 - λ)
        mean_w = (1.0 - update_w) / (1.0 - lam[None, :]) / q
        mu = (1.0 - powers[q]) / (1.0 - lam) / q  # (1/q) Σ_{j<q} λ^j
        w = delta @ update_w  # (n, 6): Σ_i λ^(q-1-i) δ_i
        lam_q = powers[q]
        n = len(delta)
        Z = np.empty((n, N_STATES), dtype=complex)  # state at each block start
        z_end = np.empty(N_STATES, dtype=complex)
        for i in range(N_STATES):
            # y[m] = λ^q y[m-1] + b w[m] with y[-1] = z0: y[m] is the start of block m+1
            y, _ = lfilter([b[i]], [1.0, -lam_q[i]], w[:, i], zi=[lam_q[i] * z0[i]])
            Z[0, i] = z0[i]
            Z[1:, i] = y[:-1]
            z_end[i] = y[-1]
        Zbar = Z * mu[None, :] + (delta @ mean_w) * b[None, :]
        out[:] = (Zbar @ (C @ W).T).real + np.outer(delta_mean, D)
        return W @ z_end

    def _plain(self, Ad, Bd, C, D, delta, x, out):
        xr = x.real.copy()
        for m in range(len(delta)):
            acc = np.zeros(4)
            for d in delta[m]:
                acc += C @ xr + D * d
                xr = Ad @ xr + Bd * d
            out[m] = acc / self.q
        return xr.astype(complex)


def simulate_outputs(theta, known: KnownParameters, steering_wheel_angle, speed, dt: float) -> np.ndarray:
    """Noise-free outputs (N, 4) of one parameter set at every sample (block of 1)."""
    return BlockSimulator(known, steering_wheel_angle, speed, dt, block=1).block_means(theta)
