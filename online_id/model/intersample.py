"""The inputs between two samples, as a logger sees a continuous car, and the exact step they drive.

A data logger samples the steering-wheel angle and the speed of a continuous car at 25-1000 Hz. Holding
each sample's input constant until the next (zero-order hold) lags the input by half a sample: 5 ms at
100 Hz, 20 ms at 25 Hz, against a tyre lag b/V of about 30 ms. The relaxation lengths then soak up the lag
and the verdict blames the model (issue 36). Here the input between samples t_k and t_k+1 is a polynomial
in the normalised time s = (t − t_k)/T, T = t_k+1 − t_k:

* ``"hold"``: δ(s) = δ_k (zero-order hold; what every path did before issue 36, kept for comparison);
* ``"linear"``: δ(s) = δ_k + s (δ_k+1 − δ_k) (first-order hold; needs no later sample);
* ``"cubic"`` (the default): the cubic Hermite curve through δ_k and δ_k+1 with the slopes of the
  three-point (non-uniform) difference at each end, exact for a quadratic input. The slope at t_k+1 needs
  δ_k+2: a streaming filter works each sample when the next has arrived, one sample late (10 ms at 100 Hz).

Measured with the built-in chirp simulated at 1 kHz and sampled at a logger's rate, the outputs' error of
the model driven through each intersample model, in sensor-noise σ (RMS; yaw rate, a_y):
hold 1.3 / 2.9 / 12 σ at 200 / 100 / 25 Hz, linear 0.02 / 0.1 / 1.7 σ, cubic 0.000 / 0.001 / 0.19 σ.

The step's input is carried as the 4-vector of the polynomial's derivatives in s at the step's start,

    w = [δ(0), δ'(0), δ''(0), δ'''(0)]   (δ(s) = w0 + w1 s + w2 s²/2 + w3 s³/6),

and the model ẋ = Ac x + Bc δ over the step is then exactly (φ_j the φ-functions, φ_0 = exp)

    x(T) = Ad x(0) + Σ_j Γ_j w_j,   Γ_j = T φ_j+1(Ac T) Bc,   Γ_0 = Bd (the hold's input column),

computed from the matrix exponential of the augmented generator (:func:`input_columns`), or mode by mode
from an eigen-decomposition of Ac (:func:`modal_input_columns`). The recurrence Γ_j = (Ac T)⁻¹ (Γ_j−1 − T Bc / j!)
is not used: it loses (|λ| T)^-j of the digits of a slow mode λ, and a car near its critical speed has one
near zero (measured: Γ_3 off by 3e-5 relative at |λ| T = 3e-4).

The speed over a step is the mean of its two samples' (``"hold"``: the first's).
"""

from __future__ import annotations

import math

import numpy as np

#: The intersample models (module docstring); the filters' and fits' default is the last.
INTERSAMPLE = ("hold", "linear", "cubic")
DEFAULT_INTERSAMPLE = "cubic"
#: Length of a step's input vector w (the cubic's value and three derivatives in s).
ORDER = 4
#: Later samples a step's input needs beyond its end sample: what a streaming filter waits for.
LOOKAHEAD = {"hold": 0, "linear": 0, "cubic": 1}
_FACTORIAL = tuple(float(math.factorial(j)) for j in range(ORDER + 1))


def check_kind(kind: str) -> str:
    """``kind`` if it is an intersample model, else a ValueError naming the choices."""
    if kind not in INTERSAMPLE:
        raise ValueError(f"unknown intersample model {kind!r}; choose from {', '.join(INTERSAMPLE)}")
    return kind


# -- the input of one step -------------------------------------------------------------------------
def slope(t_before, u_before, t, u, t_after, u_after) -> float:
    """dδ/dt at sample (t, u) [per second] from its neighbours, None where one is missing: the three-point
    difference on a non-uniform grid (exact for a quadratic), one-sided with one neighbour, 0 with none.

    h− = t − t_before, h+ = t_after − t:  m = (h−² (u_after − u) + h+² (u − u_before)) / (h− h+ (h− + h+))."""
    if t_before is None:
        return 0.0 if t_after is None else (u_after - u) / (t_after - t)
    if t_after is None:
        return (u - u_before) / (t - t_before)
    hm, hp = t - t_before, t_after - t
    return (hm * hm * (u_after - u) + hp * hp * (u - u_before)) / (hm * hp * (hm + hp))


def step_input(kind: str, u0: float, u1: float, dt: float, m0: float = 0.0, m1: float = 0.0) -> np.ndarray:
    """w (4,) of the step from δ = ``u0`` to ``u1`` over ``dt`` [s]; ``m0``, ``m1`` the slopes at its ends
    [per second] (``"cubic"`` only; :func:`slope`)."""
    w = np.zeros(ORDER)
    w[0] = u0
    if kind == "linear":
        w[1] = u1 - u0
    elif kind == "cubic":
        a, c = m0 * dt, m1 * dt
        w[1] = a
        w[2] = 2.0 * (3.0 * (u1 - u0) - 2.0 * a - c)
        w[3] = 6.0 * (2.0 * (u0 - u1) + a + c)
    return w


def value_at(w, s):
    """δ at normalised time ``s`` (0 at the step's start, 1 at its end) of step input(s) ``w`` (..., 4)."""
    w = np.asarray(w, dtype=float)
    return w[..., 0] + s * (w[..., 1] + s * (w[..., 2] / 2.0 + s * w[..., 3] / 6.0))


def split_step(w, parts: int) -> np.ndarray:
    """The inputs (parts, 4) of ``parts`` equal sub-steps of a step with input ``w`` (4,): the same curve, each
    piece's derivatives at its own start in its own normalised time (a gap bridged in sub-steps)."""
    w = np.asarray(w, dtype=float)
    a = np.arange(parts) / parts
    L = 1.0 / parts
    out = np.empty((parts, ORDER))
    out[:, 0] = value_at(w, a)
    out[:, 1] = (w[1] + a * (w[2] + a * w[3] / 2.0)) * L
    out[:, 2] = (w[2] + a * w[3]) * L * L
    out[:, 3] = w[3] * L ** 3
    return out


def step_speed(kind: str, v0: float, v1: float) -> float:
    """The speed the model takes over a step from speed ``v0`` to ``v1`` [m/s]: their mean (the hold: ``v0``)."""
    return v0 if kind == "hold" else 0.5 * (v0 + v1)


class InputStream:
    """The step inputs of a stream of samples, one sample at a time (the online filters' streaming path).

    :meth:`push` takes each valid sample's time [s], road-wheel angle δ [rad] and speed [m/s] and returns the
    samples now ready to be worked, each as ``(index, w, speed)``: ``w`` (4,) and ``speed`` of the step from
    the sample before it (None for the first sample); ``index`` counts the pushed samples from 0. With
    ``"cubic"`` a sample is ready when the next has come (:data:`LOOKAHEAD`); :meth:`drain` gives the one
    waiting (its end slope one-sided). :func:`run_inputs` gives the same numbers for a whole run at once."""

    def __init__(self, kind: str = DEFAULT_INTERSAMPLE):
        self.kind = check_kind(kind)
        self._lookahead = LOOKAHEAD[kind]
        self._before: tuple | None = None  # (t, δ, V) of the last sample worked
        self._slope = 0.0  # δ's slope there [1/s]
        self._waiting: tuple | None = None  # pushed, waiting for its successor
        self._index = 0

    def push(self, t: float, delta: float, speed: float) -> list[tuple]:
        point = (t, delta, speed)
        if self._lookahead == 0:
            return [self._ready(point, None)]
        waiting, self._waiting = self._waiting, point
        return [] if waiting is None else [self._ready(waiting, point)]

    def drain(self) -> list[tuple]:
        """The sample waiting for its successor (the stream has ended), if any."""
        waiting, self._waiting = self._waiting, None
        return [] if waiting is None else [self._ready(waiting, None)]

    def seed(self, before: tuple, slope: float) -> None:
        """Continue after samples worked elsewhere (the array path): the last was ``before`` (t, δ, V), δ's
        slope there ``slope`` [1/s]. Nothing may be waiting."""
        if self._waiting is not None:
            raise RuntimeError("InputStream.seed: a sample is waiting")
        self._before, self._slope = before, float(slope)

    def _ready(self, point: tuple, after: tuple | None) -> tuple:
        t, u, v = point
        before = self._before
        if self.kind == "cubic":
            m = slope(None if before is None else before[0], None if before is None else before[1], t, u,
                      None if after is None else after[0], None if after is None else after[1])
        else:
            m = 0.0
        if before is None:
            w, speed = None, None
        else:
            w = step_input(self.kind, before[1], u, t - before[0], self._slope, m)
            speed = step_speed(self.kind, before[2], v)
        self._before, self._slope = point, m
        index = self._index
        self._index += 1
        return index, w, speed


def run_inputs(kind: str, time, delta, speed, valid=None, slopes: bool = False):
    """The step into each sample of a whole run: W (n, 4) and the step speeds (n,) [m/s], NaN rows for the
    first valid sample and for invalid ones (with ``slopes``, also δ's slope at each sample (n,) [1/s], NaN
    at the invalid ones; 0 for the hold and the linear). ``valid`` (n,) bool marks the samples that are worked (default:
    all); the others are no one's neighbours. Element for element the arithmetic of :class:`InputStream`."""
    check_kind(kind)
    t = np.asarray(time, dtype=float)
    u = np.asarray(delta, dtype=float)
    V = np.asarray(speed, dtype=float)
    n = len(t)
    idx = np.arange(n) if valid is None else np.flatnonzero(valid)
    W = np.full((n, ORDER), np.nan)
    S = np.full(n, np.nan)
    M = np.full(n, np.nan)
    M[idx] = 0.0
    if len(idx) < 2:
        return (W, S, M) if slopes else (W, S)
    tv, uv, Vv = t[idx], u[idx], V[idx]
    t0, t1, u0, u1 = tv[:-1], tv[1:], uv[:-1], uv[1:]
    dt = t1 - t0
    rows = idx[1:]
    W[rows, 0] = u0
    W[rows, 1:] = 0.0
    if kind == "linear":
        W[rows, 1] = u1 - u0
    elif kind == "cubic":
        m = np.empty(len(idx))
        hm, hp = dt[:-1], dt[1:]  # at the inner samples 1..K-2
        m[1:-1] = (hm * hm * (uv[2:] - uv[1:-1]) + hp * hp * (uv[1:-1] - uv[:-2])) / (hm * hp * (hm + hp))
        m[0] = (uv[1] - uv[0]) / (tv[1] - tv[0])
        m[-1] = (uv[-1] - uv[-2]) / (tv[-1] - tv[-2])
        M[idx] = m
        a, c = m[:-1] * dt, m[1:] * dt
        W[rows, 1] = a
        W[rows, 2] = 2.0 * (3.0 * (u1 - u0) - 2.0 * a - c)
        W[rows, 3] = 6.0 * (2.0 * (u0 - u1) + a + c)
    S[rows] = Vv[:-1] if kind == "hold" else 0.5 * (Vv[:-1] + Vv[1:])
    return (W, S, M) if slopes else (W, S)


# -- the exact step ---------------------------------------------------------------------------------
def phi_functions(mu, order: int = ORDER):
    """φ_0(μ) … φ_order(μ) (order + 1, ...) of a real or complex array μ, each entry on its own (so a slow mode
    does not lose digits beside a fast one): φ_0 = e^μ, φ_j+1(μ) = (φ_j(μ) − 1/j!)/μ where |μ| ≥ 1 (under one
    digit lost a step), the series φ_j(μ) = Σ_n μ^n/(n + j)! below (30 terms: under 1e-30)."""
    mu = np.asarray(mu)
    out = np.empty((order + 1,) + mu.shape, dtype=np.result_type(mu, float))
    small = np.abs(mu) < 1.0
    z = np.where(small, 1.0, mu)  # (the recurrence's divisor where it applies)
    out[0] = np.exp(mu)
    for j in range(order):
        out[j + 1] = (out[j] - 1.0 / _FACTORIAL[j]) / z
    if small.any():
        zs = mu[small]
        for j in range(order + 1):
            term = np.ones_like(zs) / math.factorial(j)
            acc = term.copy()
            for n in range(1, 30):
                term = term * zs / (n + j)
                acc = acc + term
            out[j][small] = acc
    return out


def modal_input_columns(lam, W, Winv, Bc, dt) -> np.ndarray:
    """Γ (..., 6, 4) from the eigen-decomposition Ac = W diag(λ) W⁻¹: Γ_j = Re(W diag(T φ_j+1(λ T)) W⁻¹ Bc),
    each mode's φ on its own (:func:`phi_functions`). ``lam`` (..., 6), ``W``, ``Winv`` (..., 6, 6), ``dt``
    a number or (...)."""
    T = np.asarray(dt, dtype=float)
    mu = lam * T[..., None]
    phi = phi_functions(mu, ORDER)[1:]  # (4, ..., 6)
    b = np.einsum("...ij,...j->...i", Winv, np.asarray(Bc, dtype=complex))  # modal input (..., 6)
    cols = np.einsum("...ij,k...j->...ik", W, phi * b) * T[..., None, None]
    return cols.real


def input_columns(Ac, Bc, dt) -> np.ndarray:
    """Γ (..., 6, 4) of the step x(T) = Ad x(0) + Γ w (module docstring), from the matrix exponential of the
    augmented generator in normalised time (:func:`generator`; scipy's expm, batched over leading axes): exact
    whatever the modes (a car at its critical speed has one at zero). The filters' fast paths compute the same
    from their own decompositions and are tested against this. ``Ac`` (..., 6, 6), ``Bc`` (..., 6), ``dt`` T [s].

    In normalised time the chain's entries are 1 whatever T (in time units they would be T, T², T³ apart and
    scipy's Padé degree, chosen by the norm, lost ~1e-10 of Γ_3 at short periods)."""
    from scipy.linalg import expm

    Ac = np.asarray(Ac, dtype=float)
    n = Ac.shape[-1]
    return expm(generator(Ac, Bc, dt))[..., :n, n:]


def input_column_derivatives(Ac, Bc, dAc, dBc, dt) -> np.ndarray:
    """dΓ (..., K, 6, 4): Γ's derivatives along K directions in which Ac and Bc move by ``dAc`` (..., K, 6, 6)
    and ``dBc`` (..., K, 6), by Van Loan's block identity on the augmented generator (the Fréchet derivative
    of expm: the top-right block of expm([[M, dM], [0, M]]))."""
    from scipy.linalg import expm

    Ac = np.asarray(Ac, dtype=float)
    dAc = np.asarray(dAc, dtype=float)
    n = Ac.shape[-1]
    T = np.asarray(dt, dtype=float)
    M = generator(Ac, Bc, dt)[..., None, :, :]
    dM = np.zeros(dAc.shape[:-2] + M.shape[-2:])
    dM[..., :n, :n] = dAc * T[..., None, None, None]
    dM[..., :n, n] = dBc * T[..., None, None]
    N = M.shape[-1]
    big = np.zeros(dM.shape[:-2] + (2 * N, 2 * N))
    big[..., :N, :N] = M
    big[..., N:, N:] = M
    big[..., :N, N:] = dM
    return expm(big)[..., :N, N:][..., :n, n:]


def generator(Ac, Bc, dt) -> np.ndarray:
    """The augmented generator (..., 10, 10) of the state and the input's derivatives w in normalised time
    s = t/T: [[Ac T, Bc T e₀ᵀ], [0, N]], N the shift (w_j' = w_j+1). Its exponential carries [x; w] over a step
    driven by a cubic input exactly: the top rows are [Ad, Γ]."""
    Ac = np.asarray(Ac, dtype=float)
    n = Ac.shape[-1]
    T = np.asarray(dt, dtype=float)[..., None, None]
    M = np.zeros(np.broadcast_shapes(Ac.shape[:-2], T.shape[:-2]) + (n + ORDER, n + ORDER))
    M[..., :n, :n] = Ac * T
    M[..., :n, n] = np.asarray(Bc, dtype=float) * T[..., 0]
    for j in range(ORDER - 1):
        M[..., n + j, n + j + 1] = 1.0
    return M


def reference_step(Ac, Bc, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Ad (6, 6) and Γ (6, 4) by scipy's expm of the augmented generator (for tests)."""
    from scipy.linalg import expm

    n = len(Bc)
    Phi = expm(generator(Ac, Bc, dt))
    return Phi[:n, :n], Phi[:n, n:]
