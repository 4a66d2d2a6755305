"""Full-rate simulation with extra axle forces: the base model plus a force law of the slip angles.

The base model's tyre forces are F_i = −D_i·α_i. An unmodelled force law (for example a tyre
that saturates, :mod:`online_id.effects.tire_saturation`) is written as the linear force plus a
correction w_i(α_i) = F_i(α_i) + D_i·α_i that enters the yaw and lateral equations (eqs 2-3)
as a generalised force:

    E ẋ = A x + B δ + G w,   G[yaw] = [l1, −l2],  G[lateral] = [1, 1].

Discretised with δ held over each sample and w by the trapezoid, x[k+1] = Ad x[k] + Bd [δ[k], w̄[k]] with
w̄[k] = (w(x[k]) + w(x[k+1]))/2, solved by fixed-point iteration in each sample: second order in the
sample period (w held at w(x[k]), first order, was about one noise σ off the exact solution at 0.9 g and
1 kHz; the online filters' RK4 model, online_id/model/tyres.py, agrees with this to ~1e-3 of that).
The outputs take the force at the sample, w(x[k]). With a steering that is not held over a sample
(``intersample`` "linear" or "cubic", :mod:`online_id.model.intersample`), δ enters each step exactly through
its input polynomial u[k] (4,), x[k+1] = Ad x[k] + Γ u[k] + Bw w̄[k] (Γ from
:func:`online_id.sim.levels.modal_form`), the force still by its trapezoid; the blocks' speed is then the mean of
their steps' speeds (each the mean of its two samples').
Speed is held over blocks of ``hold`` samples at the block's mean, grouped into speed levels
(:mod:`online_id.sim.levels`; ``hold=1``: every sample at its own level, to 1e-3 relative), so
the model is decomposed once per level, not per sample. :func:`simulate_with_forces` solves the
recursion exactly as written, either by a plain loop over samples (``method="loop"``, the
reference) or by fixed-point iteration on whole signals (``method="picard"``, used for fitting),
which converges while the force correction is a moderate fraction of the linear force. One
Picard sweep costs a compiled loop over blocks (:func:`online_id.sim.block_loop.level_recursion`) plus
``hold`` vectorised steps inside all blocks at once (in each level's modal coordinates).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from online_id.errors import OnlineIdError
from online_id.model import intersample as its
from online_id.model.lateral import A1, A2, N_STATES
from online_id.sim.levels import ModalForm, modal_form, speed_levels
from online_id.vehicle.parameters import KnownParameters

#: A force law: slip angles (..., 2) [rad] → correction w (..., 2) [N] to the linear forces −D·α.
ForceLaw = Callable[[np.ndarray], np.ndarray]
#: Calls that go straight to the loop after the fixed point failed (then it is tried again): a fit's next
#: parameter sets are close to the last, and a failed iteration costs about half a loop.
LOOP_STREAK = 20
#: Fixed-point iterations of the trapezoid in one sample of the loop (2-4 reach round-off at 1 kHz).
TRAPEZOID_ITERATIONS = 20


class _Schedule:
    """The run cut into blocks of ``hold`` samples at their mean speed, and the model at each level; the
    steering held over each sample, or (``intersample``) its input polynomial u (n, 4) through Γ."""

    def __init__(self, theta, known: KnownParameters, delta: np.ndarray, speed: np.ndarray, dt: float, hold: int,
                 intersample: str = "hold"):
        n = len(delta)
        self.n, self.h = n, hold
        self.n_blocks = -(-n // hold)
        pad = self.n_blocks * hold - n
        self.delta = np.concatenate([delta, np.zeros(pad)])
        self.u = None  # each sample's step input polynomial (n_blocks·h, 4), None for the hold
        if intersample != "hold":
            from online_id.sim.block_means import step_inputs

            u, speed = step_inputs(intersample, delta, speed, dt)  # the speed of each sample's step
            self.u = np.concatenate([u, np.zeros((pad, its.ORDER))])
        V = np.concatenate([speed, np.repeat(speed[-1:], pad)]).reshape(self.n_blocks, hold)
        levels, self.lev = speed_levels(V.mean(axis=1))
        self.form: ModalForm = modal_form(np.asarray(theta, dtype=float)[None, :], levels, known, dt, forces=True,
                                          intersample=intersample)
        f = self.form
        self.modal = bool(f.ok.all())
        # per block: modal inputs b (n, 6, 3), powers μ^j (n, h+1, 6); output matrices per block
        self.b = f.b[0, self.lev]
        self.mu = f.mu[0, self.lev]
        self.W, self.Winv = f.W[0, self.lev], f.Winv[0, self.lev]
        self.C, self.D = f.C[0, self.lev], f.D[0, self.lev]
        self.mu_h = self.mu ** hold
        self.bT = np.swapaxes(self.b, 1, 2)
        if self.u is not None:  # the steering's modal input columns W⁻¹Γ (n_blocks, 4, 6)
            self.gT = np.swapaxes(self.Winv @ f.Gamma[0, self.lev], 1, 2)
        # block transition Φ = W diag(μ^h) W⁻¹ (real), per level
        self.Phi = np.ascontiguousarray(((f.W[0] * (f.mu[0] ** hold)[:, None, :]) @ f.Winv[0]).real)

    def per_sample(self, M: np.ndarray) -> np.ndarray:
        """A per-block array (n_blocks, ...) repeated for each sample of its block, trimmed to n."""
        return np.repeat(M, self.h, axis=0)[: self.n]

    def inputs(self, w: np.ndarray) -> np.ndarray:
        """u (n_blocks·h, 3) = [δ, w1, w2] (w padded with zeros)."""
        u = np.zeros((self.n_blocks * self.h, 3))
        u[:, 0] = self.delta
        u[: self.n, 1:] = w
        return u

    def states(self, w: np.ndarray) -> np.ndarray:
        """States (n, 6) of the linear recursion driven by δ and the forces w (n, 2), from rest."""
        if not self.modal:
            return self.loop(None, w)
        from online_id.sim.block_loop import level_recursion  # compiled (numba), imported when first needed

        h, nb = self.h, self.n_blocks
        if self.u is None:
            v = self.inputs(w).reshape(nb, h, 3) @ self.bT  # (nb, h, 6) modal inputs
        else:  # the steering through its modal Γ, the forces through their columns of b
            v = self.u.reshape(nb, h, its.ORDER) @ self.gT + self.inputs(w)[:, 1:].reshape(nb, h, 2) @ self.bT[:, 1:]
        # input accumulated over each block: c = Σ_j μ^(h-1-j) v_j, and the same in state space, g = W c
        c = np.zeros((nb, N_STATES), dtype=complex)
        for j in range(h):
            c = c * self.mu + v[:, j]
        g = (self.W @ c[..., None])[..., 0].real
        X0 = np.empty((nb, N_STATES))  # state at each block start
        level_recursion(self.Phi, np.ascontiguousarray(self.lev, dtype=np.int64), np.ascontiguousarray(g), X0)
        z = (self.Winv @ X0[..., None])[..., 0]
        Z = np.empty((nb, N_STATES, h), dtype=complex)
        for j in range(h):
            Z[:, :, j] = z
            z = z * self.mu + v[:, j]
        return np.swapaxes((self.W @ Z).real, 1, 2).reshape(nb * h, N_STATES)[: self.n]

    def loop(self, force_law: ForceLaw | None, w_fixed: np.ndarray | None = None) -> np.ndarray:
        """States (n, 6) by the plain recursion, sample by sample (the reference); fills ``self.w_loop``."""
        Ad, Bd = self.form.Ad[0], self.form.Bd[0]
        lev = self.per_sample(self.lev)
        if self.u is None:
            drive = np.einsum("ni,n->ni", Bd[lev, :, 0], self.delta[: self.n])  # Bd δ of each sample
        else:
            drive = np.einsum("nij,nj->ni", self.form.Gamma[0][lev], self.u[: self.n])  # Γ u of each sample
        Bw = Bd[:, :, 1:]
        states = np.empty((self.n, N_STATES))
        w = np.zeros((self.n, 2)) if w_fixed is None else np.asarray(w_fixed, dtype=float)
        x = np.zeros(N_STATES)
        for k in range(self.n):
            states[k] = x
            m = lev[k]
            base = Ad[m] @ x + drive[k]
            if force_law is not None:  # the trapezoid over the sample: w = (w(x[k]) + w(x[k+1]))/2, solved
                w_now = force_law(x[A1:A2 + 1])
                we = w_now
                for _ in range(TRAPEZOID_ITERATIONS):
                    nxt = 0.5 * (w_now + force_law((base + Bw[m] @ we)[A1:A2 + 1]))
                    done = np.max(np.abs(nxt - we)) <= 1e-13 * max(1.0, np.max(np.abs(nxt)))
                    we = nxt
                    if done:
                        break
                w[k] = we
            x = base + Bw[m] @ w[k]
        self.w_loop = w
        return states

    def outputs(self, states: np.ndarray, w: np.ndarray) -> np.ndarray:
        u = self.inputs(w)[: self.n]
        C, D = self.per_sample(self.C), self.per_sample(self.D)
        return np.einsum("nij,nj->ni", C, states) + np.einsum("nij,nj->ni", D, u)


def simulate_with_forces(theta, known: KnownParameters, steering_wheel_angle, speed, dt: float,
                         force_law: ForceLaw | None = None, method: str = "picard", tol: float = 1e-9,
                         max_iterations: int = 200, warm: dict | None = None,
                         hold: int = 1, intersample: str = "hold") -> tuple[np.ndarray, np.ndarray]:
    """States (N, 6) and noise-free outputs (N, 4) with an extra force law (None: the base model).

    ``speed`` is a scalar or one value per sample [m/s], held over blocks of ``hold`` samples at
    their mean (``hold`` = the block of :class:`~online_id.sim.block_means.BlockSimulator` makes the two
    agree exactly without a force law, for the same ``intersample``: the steering between samples, module
    docstring). ``warm``, a dict kept by the caller across calls with nearby
    parameters (a fit), starts each fixed-point iteration from the last forces.
    """
    if method not in ("loop", "picard"):
        raise ValueError(f"unknown method {method!r}; choose loop or picard")
    dH = np.asarray(steering_wheel_angle, dtype=float)
    n = len(dH)
    V = np.broadcast_to(np.asarray(speed, dtype=float), (n,))
    with np.errstate(all="ignore"):
        sched = _Schedule(theta, known, dH / known.steering_ratio, np.asarray(V, dtype=float), dt, int(hold),
                          its.check_kind(intersample))
        if force_law is None:
            w = np.zeros((n, 2))
            states = sched.states(w)
        elif method == "loop":
            states = sched.loop(force_law)
            w = sched.w_loop
        else:
            warm = {} if warm is None else warm
            start = warm.get("w")
            w = start.copy() if start is not None and start.shape == (n, 2) else np.zeros((n, 2))
            if warm.get("loop_calls", 0) > 0:  # the last call needed the loop: nearby parameters will too
                warm["loop_calls"] -= 1
                states = sched.loop(force_law)
                w = sched.w_loop
            else:
                states, w, looped = _picard(sched, w, force_law, tol, max_iterations)
                if looped:
                    warm["loop_calls"] = LOOP_STREAK
            warm["w"] = w.copy()
        if force_law is not None:
            w = force_law(states[:, [A1, A2]])  # the outputs see the force at each sample
        return states, sched.outputs(states, w)


#: Past iterates Anderson acceleration combines (Walker & Ni 2011: a few are enough).
ANDERSON_DEPTH = 5
#: Iterations without a new smallest residual after which the iteration is judged to diverge (a car
#: that spins in simulation has no whole-signal fixed point to find) and the plain loop takes over.
STALL_ITERATIONS = 8


def _trapezoid(w_at_samples: np.ndarray) -> np.ndarray:
    """w̄[k] = (w[k] + w[k+1])/2 (the last sample: its own, only the state after the run depends on it)."""
    out = w_at_samples.copy()
    out[:-1] = 0.5 * (w_at_samples[:-1] + w_at_samples[1:])
    return out


def _picard(sched: _Schedule, w: np.ndarray, force_law: ForceLaw, tol: float, max_iterations: int):
    """Fixed point of w̄ = trapezoid(force_law(α(w̄))) on the whole run: (states, w, whether the loop was needed).

    Plain fixed-point iteration w ← g(w) contracts only while the force law's slope stays well
    below the linear stiffness; deep in saturation its factor tends to 1. Anderson acceleration
    (type II, depth :data:`ANDERSON_DEPTH`: the next iterate is the combination of the last g(w)
    that best cancels the last residuals g(w) − w, a secant method on the whole signal) keeps it
    converging there. If it still does not converge, the plain loop over samples is used.
    """
    scale = max(np.max(np.abs(w)), 1.0) if np.any(w) else None
    dF: list[np.ndarray] = []
    dG: list[np.ndarray] = []
    last_f = last_g = None
    best, since_best = np.inf, 0
    for _ in range(max_iterations):
        states = sched.states(w)
        g = _trapezoid(force_law(states[:, [A1, A2]]))
        if not np.all(np.isfinite(g)):
            break
        f = (g - w).ravel()
        if scale is None:
            scale = max(np.max(np.abs(g)), 1.0)
        size = np.max(np.abs(f), initial=0.0)
        if size <= tol * scale:
            return sched.states(g), g, False
        best, since_best = (size, 0) if size < best else (best, since_best + 1)
        if since_best >= STALL_ITERATIONS:
            break
        if last_f is not None:
            dF.append(f - last_f)
            dG.append(g.ravel() - last_g)
            if len(dF) > ANDERSON_DEPTH:
                dF.pop(0)
                dG.pop(0)
        last_f, last_g = f, g.ravel()
        if dF:
            F = np.stack(dF, axis=1)
            if not np.all(np.isfinite(F)):  # differences that overflowed: the plain loop below takes over
                break
            gamma = np.linalg.lstsq(F, f, rcond=None)[0]
            w = (g.ravel() - np.stack(dG, axis=1) @ gamma).reshape(g.shape)
        else:
            w = g
    try:
        states = sched.loop(force_law)
    except FloatingPointError:
        states = None
    if states is None or not np.all(np.isfinite(states)):
        raise OnlineIdError("the force law did not converge (the tyres are too far into saturation for this"
                            " simulation)")
    return states, sched.w_loop, True
