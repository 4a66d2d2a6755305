"""Fast exact simulation of many parameter sets over one run's inputs (batch fit, diagnosis, polish).

:class:`BlockSimulator` returns the *mean of each output over blocks of q samples*. Within a block
the speed is taken constant at the block's mean speed; for a constant-speed run this is the
zero-order-hold model of :func:`online_id.sim.simulator.propagate` to round-off. On a run whose
speed varies, the block-mean speed differs from each sample's by about half the speed change over
a block (a race car: at most 0.5 m/s at 1 g over a 0.1 s block); the test against the per-sample
recursion bounds the effect on the block means.

For a block of q samples at one speed, with x the state at its start and δ_0..δ_{q-1} its inputs,

    x_next = Φ x + Γ δ,   ȳ = H x + K δ,
    Φ = Ad^q,  Γ[:, i] = Ad^(q-1-i) Bd,  H = C Σ_{j<q} Ad^j / q,  K[:, i] = (C Σ_{j<q-1-i} Ad^j Bd + D) / q,

exactly (ȳ the mean of y_j = C x_j + D δ_j over the block). With a steering that is not held over a sample
(``intersample`` "linear" or "cubic", :mod:`online_id.model.intersample`) each sample's step takes its input
polynomial w_i (4,) through the exact step x ← Ad x + Γ w_i (Γ (6, 4), :func:`online_id.sim.levels.modal_form`),
and the block maps take the 4q numbers of a block's inputs, laid out sample after sample:

    Γ_block[:, 4i + j] = Ad^(q-1-i) Γ_j,   K[:, 4i + j] = (C Σ_{l<q-1-i} Ad^l Γ_j + [j = 0] D) / q,

(w_i,0 = δ_i, the value at the sample). On an even grid each w_i is linear in the values and slopes (times T) of
the samples at its ends, w_i = L [δ_i, δ_i+1, a_i, a_i+1] (:func:`input_basis`), so a block's 4q numbers come from
its q + 1 samples' 2(q + 1) (the linear: their q + 1 values): the maps are taken in that basis, Γ_block·M and K·M,
and the same compiled loops run over inputs (n_blocks, 2(q + 1)) (the fit's 10-sample blocks at 1 kHz: 22 numbers
a block, not 40; a GA generation 1.5× the hold's where the 4q layout took 2.5×). The block's speed is then the
mean of its steps' speeds (each the mean of its two samples', :func:`online_id.model.intersample.step_speed`).

These block maps depend only on the parameter set and the speed, so they are never built per block:

- constant speed (all block speeds within ``speed_tolerance``, relative): one set of maps, and the
  recursion x ← Φ x + Γ δ and the means run compiled in one pass
  (:func:`online_id.sim.block_loop.constant_block_means`, numba: about 3.5 ms for the built-in run's 12,000
  blocks of nine parameter sets, where a modal run through scipy.signal.lfilter took 64 ms and scipy.signal
  0.3-0.5 s to import);
- varying speed: the maps are built exactly on a geometric grid of speeds (relative spacing
  :data:`SPEED_GRID_STEP`, one batched eigen-decomposition for every grid speed and parameter set,
  :func:`online_id.sim.levels.modal_form`) and interpolated linearly in V between the two grid
  speeds around each block's. The maps are smooth in V (the model's coefficients are in V and
  1/V), so the interpolation error is at most h²/8·max‖∂²M/∂V²‖ for grid spacing h; at 2 % it
  is below 1e-4 of each output's range on the race car's 16-61 m/s (tests/test_fit.py checks
  it against the maps built at every block's own speed). The interpolation, the recursion and the means then
  run block by block in one compiled pass (:func:`online_id.sim.block_loop.varying_block_means`), carrying
  every parameter set at once.

:meth:`BlockSimulator.block_means` takes one parameter set (8,) or a stack (P, 8); a stack costs
little more than one (the batched finite-difference Jacobians of the fits rely on it).
"""

from __future__ import annotations

from collections import OrderedDict

import numpy as np

from online_id.errors import OnlineIdError
from online_id.model import intersample as its
from online_id.model.lateral import N_OUTPUTS, N_STATES
from online_id.sim.levels import SPEED_TOLERANCE, modal_form
from online_id.vehicle.parameters import KnownParameters

#: Relative spacing of the speed grid on which the block maps are built when speed varies (module docstring).
SPEED_GRID_STEP = 0.02
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


def block_input_maps(Ad, Gamma, C, D, q: int):
    """Φ (..., 6, 6), Γ_block (..., 6, 4q), H (..., 4, 6), K (..., 4, 4q) of q samples at one speed, each sample's
    step driven by its input polynomial w (4,) through Γ (..., 6, 4) (module docstring); D (..., 4) of δ."""
    power = np.broadcast_to(np.eye(N_STATES), Ad.shape).copy()
    sums = [np.zeros_like(Ad)]  # sums[n] = Σ_{j<n} Ad^j
    powers_g = []  # Ad^j Γ
    for _ in range(q):
        powers_g.append(power @ Gamma)
        sums.append(sums[-1] + power)
        power = power @ Ad
    Gamma_block = np.concatenate(powers_g[::-1], axis=-1)  # columns 4i..4i+3: Ad^(q-1-i) Γ
    H = C @ sums[q] / q
    K = []
    for i in range(q):
        Ki = C @ sums[q - 1 - i] @ Gamma
        Ki[..., 0] += D
        K.append(Ki)
    return power, Gamma_block, H, np.concatenate(K, axis=-1) / q


def input_basis(kind: str, q: int) -> np.ndarray:
    """M (4q, m): a block's step inputs w (its q steps' 4 numbers, sample after sample) from its q + 1 samples'
    values and slopes times the period, x = [δ_0..δ_q, a_0..a_q] (m = 2(q + 1); the linear: [δ_0..δ_q], m = q + 1):
    w_i = L [δ_i, δ_i+1, a_i, a_i+1], the arithmetic of :func:`online_id.model.intersample.step_input`:
    linear w = [δ_i, δ_i+1 − δ_i, 0, 0]; cubic w = [δ_i, a_i, 6(δ_i+1 − δ_i) − 4a_i − 2a_i+1,
    12(δ_i − δ_i+1) + 6(a_i + a_i+1)]."""
    its.check_kind(kind)
    if kind == "hold":
        raise ValueError("input_basis: the hold takes each sample's δ as it is")
    L = {"linear": [[1, 0, 0, 0], [-1, 1, 0, 0], [0, 0, 0, 0], [0, 0, 0, 0]],
         "cubic": [[1, 0, 0, 0], [0, 0, 1, 0], [-6, 6, -4, -2], [12, -12, 6, 6]]}[kind]
    m = (q + 1) * (2 if kind == "cubic" else 1)
    M = np.zeros((its.ORDER * q, m))
    for i in range(q):
        cols = [i, i + 1, q + 1 + i, q + 2 + i][: 2 if kind == "linear" else 4]
        M[its.ORDER * i: its.ORDER * (i + 1), cols] = np.asarray(L, dtype=float)[:, : len(cols)]
    return M


def block_inputs(kind: str, delta, q: int, n_blocks: int) -> np.ndarray:
    """Each block's inputs in :func:`input_basis`'s basis (n_blocks, m): the values δ (and, cubic, the slopes times
    the period, :func:`even_slopes`) of its q + 1 samples, the last being the next
    block's first (after the run: the last sample's, whose step no output sees)."""
    u = np.asarray(delta, dtype=float)
    n = len(u)
    index = np.minimum(np.arange(n_blocks)[:, None] * q + np.arange(q + 1)[None, :], n - 1)
    if kind == "linear":
        return u[index]
    return np.concatenate([u[index], even_slopes(u)[index]], axis=1)


def even_slopes(u) -> np.ndarray:
    """The cubic's slope times the period at each sample of ``u`` (n,) on an even grid: the four-point
    a_k = (2 δ_k+1 + 3 δ_k − 6 δ_k−1 + δ_k−2)/6 where two samples come before, the central (δ_k+1 − δ_k−1)/2 at
    the second, one-sided at the run's ends (:func:`online_id.model.intersample.slope`, computed as such)."""
    u = np.asarray(u, dtype=float)
    n = len(u)
    a = np.zeros(n)
    if n > 1:
        a[1:-1] = 0.5 * (u[2:] - u[:-2])
        a[0], a[-1] = u[1] - u[0], u[-1] - u[-2]
    if n > 3:
        a[2:-1] = (2.0 * u[3:] + 3.0 * u[2:-1] - 6.0 * u[1:-2] + u[:-3]) / 6.0
    return a


def step_inputs(kind: str, delta, speed, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """The input polynomial w (n, 4) and the speed (n,) of each sample's step to the next (the last sample's:
    its own δ held, at its speed), for road-wheel angles ``delta`` (n,) [rad] and ``speed`` (n,) [m/s] sampled
    every ``dt`` [s]: the numbers of :func:`online_id.model.intersample.run_inputs` on an even grid, its slopes
    those of :func:`even_slopes`, computed as such (to round-off the same; a tenth of the time on the 600,000
    samples of a run simulated at 10 kHz)."""
    its.check_kind(kind)
    u = np.asarray(delta, dtype=float)
    V = np.asarray(speed, dtype=float)
    n = len(u)
    w = np.zeros((n, its.ORDER))
    w[:, 0] = u
    if n < 2 or kind == "hold":
        return w, V.copy()
    du = u[1:] - u[:-1]
    if kind == "linear":
        w[:-1, 1] = du
    else:
        a = even_slopes(u)  # the slope at each sample times T
        w[:-1, 1] = a[:-1]
        w[:-1, 2] = 2.0 * (3.0 * du - 2.0 * a[:-1] - a[1:])
        w[:-1, 3] = 6.0 * (a[:-1] + a[1:] - 2.0 * du)
    return w, step_speeds(V)


def step_speeds(speed) -> np.ndarray:
    """The speed (n,) [m/s] of each sample's step to the next when the inputs between samples are not held: the
    mean of its two samples' (:func:`online_id.model.intersample.step_speed`); the last sample's, its own."""
    V = np.asarray(speed, dtype=float)
    out = V.copy()
    out[:-1] = 0.5 * (V[:-1] + V[1:])
    return out


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
    intersample : the steering between samples, ``"hold"`` (each sample's held), ``"linear"`` or ``"cubic"``
        (:mod:`online_id.model.intersample`; module docstring)
    """

    def __init__(self, known: KnownParameters, steering_wheel_angle, speed, dt: float, block: int = 1,
                 speed_tolerance: float = SPEED_TOLERANCE, intersample: str = "hold"):
        if block < 1:
            raise ValueError("block must be at least 1")
        self.known, self.dt, self.q = known, float(dt), int(block)
        self.intersample = its.check_kind(intersample)
        dH = np.asarray(steering_wheel_angle, dtype=float)
        V = np.broadcast_to(np.asarray(speed, dtype=float), dH.shape)
        self.n_blocks = len(dH) // self.q
        if self.n_blocks < 1:
            raise OnlineIdError(f"{len(dH)} sample(s): too short for one block of {self.q}")
        self.n_used = self.n_blocks * self.q
        if intersample == "hold":
            #: each block's inputs (n_blocks, q): the held δ of its samples; else (n_blocks, m) in the basis
            #: ``basis`` (4q, m) of its steps' input polynomials (:func:`input_basis`, module docstring)
            self.delta = (dH[: self.n_used] / known.steering_ratio).reshape(self.n_blocks, self.q)
            self.block_speed = V[: self.n_used].reshape(self.n_blocks, self.q).mean(axis=1)
            self.basis = None
        else:
            self.delta = block_inputs(intersample, dH / known.steering_ratio, self.q, self.n_blocks)
            self.basis = input_basis(intersample, self.q)
            self.block_speed = step_speeds(V)[: self.n_used].reshape(self.n_blocks, self.q).mean(axis=1)
        vmin, vmax = float(self.block_speed.min()), float(self.block_speed.max())
        self.constant_speed = vmax - vmin <= speed_tolerance * abs(vmin)
        if self.constant_speed:
            self.grid = np.array([float(self.block_speed.mean())])
            self.lower = np.zeros(self.n_blocks, dtype=int)
            self.weight = np.zeros(self.n_blocks)
        else:
            n_grid = int(np.ceil(np.log(vmax / vmin) / np.log1p(SPEED_GRID_STEP))) + 1
            self.grid = vmin * np.exp(np.linspace(0.0, np.log(vmax / vmin), n_grid))
            self.lower = np.clip(np.searchsorted(self.grid, self.block_speed, side="right") - 1, 0, n_grid - 2)
            self.weight = (self.block_speed - self.grid[self.lower]) / np.diff(self.grid)[self.lower]
        self._cache: OrderedDict[bytes, np.ndarray] = OrderedDict()
        self.simulations = 0  # parameter sets simulated (cache misses)

    def block_means(self, theta) -> np.ndarray:
        """Mean of each output [r, φ, p, a_y, v_y] over each block: (n_blocks, 5) for theta (8,),
        (P, n_blocks, 5) for a stack (P, 8)."""
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
            form = modal_form(thetas, self.grid, self.known, self.dt, intersample=self.intersample)
            if form.Gamma is None:
                Phi, Gamma, H, K = block_maps(form.Ad, form.Bd[..., 0], form.C, form.D[..., 0], q)
            else:
                Phi, Gamma, H, K = block_input_maps(form.Ad, form.Gamma, form.C, form.D[..., 0], q)
                Gamma, K = Gamma @ self.basis, K @ self.basis
            if self.constant_speed:  # one pass, compiled (numba), imported when first needed
                from online_id.sim.block_loop import constant_block_means

                out = np.empty((P, self.n_blocks, N_OUTPUTS))
                constant_block_means(*(np.ascontiguousarray(M[:, 0]) for M in (Phi, Gamma, H, K)),
                                     np.ascontiguousarray(self.delta), out)
                return out
            # varying speed: maps interpolated between the grid speeds around each block's, in one compiled pass
            from online_id.sim.block_loop import varying_block_means

            out = np.empty((P, self.n_blocks, N_OUTPUTS))
            varying_block_means(*(np.ascontiguousarray(M) for M in (Phi, Gamma, H, K)),
                                np.ascontiguousarray(self.lower, dtype=np.int64),
                                np.ascontiguousarray(self.weight, dtype=float), np.ascontiguousarray(self.delta), out)
        return out


def simulate_outputs(theta, known: KnownParameters, steering_wheel_angle, speed, dt: float,
                     intersample: str = "hold") -> np.ndarray:
    """Noise-free outputs (N, 5) of one parameter set at every sample (block of 1)."""
    return BlockSimulator(known, steering_wheel_angle, speed, dt, block=1,
                          intersample=intersample).block_means(theta)
