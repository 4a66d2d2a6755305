"""The model with saturating tyres, one sample at a time, with its derivatives (the online filters' form).

The base model's axle forces are linear, F_i = −D_i·α_i. With ``tire_saturation``
(:mod:`online_id.effects.tire_saturation`) each follows

    F_i = −μ_i·Fz_i · tanh(D_i·α_i / (μ_i·Fz_i))

(static axle loads Fz_i; the same cornering stiffness D_i at small slip, a peak force μ_i·Fz_i). Written
as the linear force plus a correction w_i = F_i + D_i·α_i that enters the yaw and lateral rows as a
generalised force (as :mod:`online_id.sim.forces` simulates it):

    E(θ) ẋ = A(θ, V) x + B(V) δ + G w(α; D, μ),   G[yaw] = [l1, −l2],  G[lateral] = [1, 1],

    ∂w_i/∂α_i = D_i tanh²(u_i),  ∂w_i/∂D_i = α_i tanh²(u_i),  ∂w_i/∂μ_i = Fz_i (u_i sech²(u_i) − tanh(u_i)),

with u_i = D_i α_i / (μ_i Fz_i). The local cornering stiffness is ∂F_i/∂α_i = −D_i sech²(u_i).

A law whose whole curve follows the axle's load (``load_sensitivity``, ``downforce``: :func:`_peaks`' six-column
loads) scales it by k_i (the load factor times the friction ellipse's share): F_i = −k_i·μ_i·Fz_i⁰·tanh(u_i), so
w_i = D_i α_i − k_i μ_i Fz_i⁰ tanh(u_i), ∂w_i/∂α_i = D_i (1 − k_i sech²(u_i)), ∂w_i/∂D_i = α_i (1 − k_i sech²(u_i)),
∂w_i/∂μ_i = k_i Fz_i⁰ (u_i sech²(u_i) − tanh(u_i)) − (∂k_i/∂μ_i) μ_i Fz_i⁰ tanh(u_i). With k_i = 1 the kernels take
the arithmetic above, bit for bit.

Integration: classical Runge-Kutta (RK4) over each sample period of length T, in ``n`` equal sub-steps of
h = T/n with h·V/min(b) ≤ 0.5 (one sub-step at 1 kHz; the tyre lag V/b is the stiffest mode), V held (the
step's speed). The steering follows the step's input curve (:func:`step_input`, :mod:`online_id.model.intersample`:
w = [δ(0), δ'(0), δ''(0), δ'''(0)] in the normalised time s = t/T, δ(s) = w0 + w1 s + w2 s²/2 + w3 s³/6):
sub-step i's stages take δ(s) + g·e at s = (i + c)/n, c = 0, ½, ½, 1 (RK4's stage times), g·e the extra
states' steering shift; the hold's w = [δ, 0, 0, 0] is δ held, the same numbers as before issue 36
(:func:`step`). The derivatives of the step with respect to the state at the step's start and to the
constants (log-scale parameters, μ, extra states) are the exact derivatives of the RK4 arithmetic (forward
mode through every stage; δ(s) depends on w and on the extra states through the shift, not on the state), so
the EKF's Jacobian is that of the map it uses for the mean. Error against a fine reference (RK4 at 64 times
finer steps with the same input; tests/test_tyre_filter.py, tests/test_intersample_filters.py), one sample
deep in the tanh (u ≈ 1) at 80 km/h: with δ held below 1e-9 of the state at 1 kHz, below 1e-5 at 100 Hz; with
a cubic input (a 4 Hz steering swing) below 1e-9 at 1 kHz and 3e-5 at 100 Hz (RK4's own error: with μ huge
the step is as far from the linear model's exact step x(T) = Ad x + Γ w), where holding δ instead is 7e-5
and 5e-3 off.
The simulator's form of the effect (online_id/sim/forces.py) agrees with this model to under 2 % of the
sensors' noise over a 0.9 g chirp. With μ large (w → 0) the step is the linear model's, to the same error.

Relaxation lengths below :data:`B_FLOOR` (5 cm) are taken as 5 cm (not a car's tyre; the stiff tyre lag would
cost hundreds of sub-steps a sample at race speeds). Everything here is compiled (numba); arrays are
float64. ``known`` is :func:`known_array`'s vector.
"""

from __future__ import annotations

import math

import numpy as np

from online_id.model.lateral import A1, A2, ARO, B1, B2, BETA, D1, D2, KRO, MXX, MZZ, N_PARAMS, N_STATES, PHI, P, R
from online_id.util.jit import cached_njit
from online_id.vehicle.parameters import KnownParameters

#: μ never enters the force law below this (an additive filter state could cross zero).
MU_FLOOR = 0.05
#: Largest h·V/min(b) of one RK4 sub-step.
MAX_STIFF_STEP = 0.5
#: Largest h·ρ(E⁻¹A) of one RK4 sub-step (RK4 is stable to about 2.8 on the real and imaginary axes).
MAX_STABLE_STEP = 2.0
#: Most RK4 sub-steps in one sample period.
MAX_SUBSTEPS = 4096
#: Shortest relaxation length the model uses [m]: below it, not a car's tyre (shorter than a contact patch),
#: and the tyre lag's V/b would need hundreds of RK4 sub-steps a sample at race speeds. The model takes
#: max(b, B_FLOOR); b's derivative is zero below it, so the data no longer move it there.
B_FLOOR = 0.05

_K_M, _K_MS, _K_MXZ, _K_H0, _K_H1, _K_H2, _K_L1, _K_L2, _K_EPS1, _K_EPS2 = range(10)


def known_array(known: KnownParameters) -> np.ndarray:
    """The known constants the kernels read, as one vector."""
    k = known
    return np.array([k.M, k.ms, k.Mxz, k.h0, k.h1, k.h2, k.l1, k.l2, k.eps1, k.eps2], dtype=float)


#: The least share of μ·Fz an axle keeps for its lateral force when its longitudinal force uses the friction
#: ellipse (:func:`_peaks`): a sample braking at the limit (or an a_x with noise beyond μ·g) leaves the axle some
#: grip instead of none, where the tanh law would have a zero peak.
MIN_PEAK_SHARE = 0.2


@cached_njit(fastmath=False)
def _peaks(mu, loads, peak, dpeak):  # pragma: no cover -- compiled
    """Each axle's peak lateral force and its derivative in μ into ``peak[:2]``, ``dpeak[:2]``, and the scale of its
    whole force curve and that scale's derivative in μ into ``peak[2:]``, ``dpeak[2:]`` (each (4,)).

    ``loads`` is [Fz1, Fz2] (peak μ_i·Fz_i, its derivative Fz_i; scale 1), or [Fz1, Fz2, Fx1, Fx2] with the axles'
    longitudinal forces, whose share of the friction ellipse the lateral force cannot have: peak
    √((μ_i·Fz_i)² − Fx_i²), at least :data:`MIN_PEAK_SHARE` of μ_i·Fz_i (derivative μ_i·Fz_i²/peak; with Fx_i = 0 the
    first form, bit for bit; scale 1). Or [Fz1⁰, Fz2⁰, Fx1, Fx2, k1, k2] (``load_sensitivity``): the static loads, the
    longitudinal forces and each axle's load factor k_i = (Fz_i/Fz_i⁰)^p; the axle's whole curve at its static load
    (peak μ_i·Fz_i⁰) is scaled by k_i·s_i, s_i = √(1 − (Fx_i/(k_i·μ_i·Fz_i⁰))²) at least :data:`MIN_PEAK_SHARE`:
    cornering stiffness and peak both follow the load (less than linearly for p < 1) and both shrink as the
    longitudinal force uses the friction ellipse."""
    scaled = loads.shape[0] == 6
    for i in range(2):
        m = max(mu[i], MU_FLOOR)
        full = m * loads[i]
        if scaled:
            peak[i] = full
            dpeak[i] = loads[i]
            k = loads[4 + i]
            fx = loads[2 + i]
            ratio = fx / (k * full) if fx != 0.0 else 0.0
            rest = 1.0 - ratio * ratio
            if rest > MIN_PEAK_SHARE * MIN_PEAK_SHARE:
                share = math.sqrt(rest)
                peak[2 + i] = k * share
                dpeak[2 + i] = k * ratio * ratio / (m * share) if mu[i] > MU_FLOOR else 0.0
            else:
                peak[2 + i] = k * MIN_PEAK_SHARE
                dpeak[2 + i] = 0.0
            continue
        peak[2 + i] = 1.0
        dpeak[2 + i] = 0.0
        fx = loads[2 + i] if loads.shape[0] == 4 else 0.0
        if fx == 0.0:
            peak[i] = full
            dpeak[i] = loads[i]
            continue
        least = MIN_PEAK_SHARE * full
        rest = full * full - fx * fx
        if rest > least * least:
            peak[i] = math.sqrt(rest)
            dpeak[i] = m * loads[i] * loads[i] / peak[i]
        else:
            peak[i] = least
            dpeak[i] = MIN_PEAK_SHARE * loads[i]


@cached_njit(fastmath=False)
def _step_loads(Fz, k, mid):  # pragma: no cover -- compiled
    """The loads of the step from sample k into k + 1: the two samples' mean into ``mid`` (second order, where the
    hold's first-order lag of half a period biased a 25 Hz run: a law whose whole curve follows the load, roll rate's
    innovations not white). Whether they differ from sample k's (else ``mid`` is not written and the caller keeps
    sample k's peaks: static loads take the arithmetic they had, bit for bit). The filters take the same mean
    (:meth:`online_id.filters.tyre_filters._TyreModel.read`)."""
    same = True
    for j in range(Fz.shape[1]):
        if Fz[k + 1, j] != Fz[k, j]:
            same = False
            break
    if same:
        return False
    for j in range(Fz.shape[1]):
        mid[j] = 0.5 * (Fz[k, j] + Fz[k + 1, j])
    return True


@cached_njit(fastmath=False)
def _static_loads(Fz, n):
    """The axle loads (2,) or (4,) (with the longitudinal forces) as every sample's (n, ·): the run kernels take them
    per sample."""
    out = np.empty((n, Fz.shape[0]))
    for k in range(n):
        for j in range(Fz.shape[0]):
            out[k, j] = Fz[j]
    return out


def per_sample_loads(Fz, n: int) -> np.ndarray:
    """Axle loads [N] as the run kernels take them, (n, 2) or (n, 4) contiguous: from static ones (2,) (or (4,) with
    the axles' longitudinal forces, :func:`_peaks`), or per sample already."""
    Fz = np.asarray(Fz, dtype=float)
    if Fz.ndim == 1 and len(Fz) in (2, 4, 6):
        return np.ascontiguousarray(np.broadcast_to(Fz, (n, len(Fz))))
    if Fz.ndim != 2 or Fz.shape[0] != n or Fz.shape[1] not in (2, 4, 6):
        raise ValueError(f"axle loads of shape {Fz.shape}, expected (2,), (4,), (6,) or ({n}, 2), ({n}, 4), ({n}, 6)")
    return np.ascontiguousarray(Fz)


@cached_njit(fastmath=False)
def floored(th):
    """θ as the model uses it: the relaxation lengths at least :data:`B_FLOOR`."""
    out = th.copy()
    out[B1] = max(th[B1], B_FLOOR)
    out[B2] = max(th[B2], B_FLOOR)
    return out


@cached_njit(fastmath=False)
def _linear_parts(th, V, kn):
    """E(θ) and A(θ, V) of the linear model E ẋ = A x + B δ (the tyres linear)."""
    M, ms, Mxz, h0 = kn[_K_M], kn[_K_MS], kn[_K_MXZ], kn[_K_H0]
    h1, h2, l1, l2, e1, e2 = kn[_K_H1], kn[_K_H2], kn[_K_L1], kn[_K_L2], kn[_K_EPS1], kn[_K_EPS2]
    msh0 = ms * h0
    E = np.zeros((6, 6))
    E[0, R] = -Mxz
    E[0, BETA] = -msh0 * V
    E[0, P] = th[MXX] + msh0 * h0
    E[1, R] = th[MZZ]
    E[1, P] = -Mxz
    E[2, BETA] = M * V
    E[2, P] = -msh0
    E[3, PHI] = 1.0
    E[4, A1] = th[B1]
    E[5, A2] = th[B2]
    A = np.zeros((6, 6))
    A[0, R] = msh0 * V
    A[0, PHI] = -th[KRO]
    A[0, P] = -th[ARO]
    A[1, A1] = -l1 * th[D1]
    A[1, A2] = l2 * th[D2]
    A[2, R] = -M * V
    A[2, A1] = -th[D1]
    A[2, A2] = -th[D2]
    A[3, P] = 1.0
    A[4, R] = l1
    A[4, BETA] = V
    A[4, PHI] = -V * e1
    A[4, P] = h1
    A[4, A1] = -V
    A[5, R] = -l2
    A[5, BETA] = V
    A[5, PHI] = -V * e2
    A[5, P] = h2
    A[5, A2] = -V
    return E, A


@cached_njit(fastmath=False)
def _inverse_parts(th, V, kn):
    """E⁻¹ and E⁻¹A at (θ, V): what every RK4 stage of a sample period shares (θ and V are held over it).

    E (:func:`_linear_parts`) couples only r, β and p, through its rows 0-2 (a 3 × 3 block G); φ, α1 and α2 sit on
    its diagonal (1, b1, b2). E⁻¹ is G⁻¹ by cofactors and the three reciprocals, E⁻¹A by loops over E⁻¹'s non-zeros:
    no LAPACK call and no product of full matrices at each sample (they were most of a tyre pass's cost, issue 40).
    A singular G (V = 0, or a parameter set with no inertia) takes LAPACK's inverse, which says so."""
    E, A = _linear_parts(th, V, kn)
    idx = (R, BETA, P)
    g00, g01, g02 = E[0, R], E[0, BETA], E[0, P]
    g10, g11, g12 = E[1, R], E[1, BETA], E[1, P]
    g20, g21, g22 = E[2, R], E[2, BETA], E[2, P]
    c00 = g11 * g22 - g12 * g21
    c01 = g12 * g20 - g10 * g22
    c02 = g10 * g21 - g11 * g20
    det = g00 * c00 + g01 * c01 + g02 * c02
    if det == 0.0 or not math.isfinite(det) or E[4, A1] == 0.0 or E[5, A2] == 0.0:
        Einv = np.linalg.inv(E)
        return Einv, Einv @ A
    Einv = np.zeros((N_STATES, N_STATES))
    inv = 1.0 / det
    Einv[idx[0], 0] = c00 * inv
    Einv[idx[0], 1] = (g02 * g21 - g01 * g22) * inv
    Einv[idx[0], 2] = (g01 * g12 - g02 * g11) * inv
    Einv[idx[1], 0] = c01 * inv
    Einv[idx[1], 1] = (g00 * g22 - g02 * g20) * inv
    Einv[idx[1], 2] = (g02 * g10 - g00 * g12) * inv
    Einv[idx[2], 0] = c02 * inv
    Einv[idx[2], 1] = (g01 * g20 - g00 * g21) * inv
    Einv[idx[2], 2] = (g00 * g11 - g01 * g10) * inv
    Einv[PHI, 3] = 1.0 / E[3, PHI]
    Einv[A1, 4] = 1.0 / E[4, A1]
    Einv[A2, 5] = 1.0 / E[5, A2]
    EA = np.zeros((N_STATES, N_STATES))
    for a in range(N_STATES):
        for c in range(N_STATES):
            acc = 0.0
            for m in range(N_STATES):
                e = Einv[a, m]
                if e != 0.0:
                    acc += e * A[m, c]
            EA[a, c] = acc
    return Einv, EA


@cached_njit(fastmath=False)
def _tyre_terms(x, D, peak, mu, dpeak):  # pragma: no cover -- compiled
    """The tyres' correction to the linear force per axle, w = Dα − μFz·tanh(Dα/(μFz)) (2,), and its derivatives
    with respect to α, D and μ (0 for an axle whose μ is at the floor), at the slip angles of x; ``D`` (2,) the
    cornering stiffnesses, ``peak`` (2,) the peak forces (max(μ, MU_FLOOR)·Fz) and ``dpeak`` (2,) their derivatives in
    μ (Fz; with a longitudinal force on the friction ellipse, :func:`_peaks`'s)."""
    w = np.empty(2)
    dw_a = np.empty(2)
    dw_D = np.empty(2)
    dw_mu = np.empty(2)
    for i in range(2):
        alpha = x[A1 + i]
        u = D[i] * alpha / peak[i]
        t = math.tanh(u)
        k = peak[2 + i]
        if k == 1.0 and dpeak[2 + i] == 0.0:
            w[i] = D[i] * alpha - peak[i] * t
            dw_a[i] = D[i] * t * t
            dw_D[i] = alpha * t * t
            dw_mu[i] = dpeak[i] * (u * (1.0 - t * t) - t) if mu[i] > MU_FLOOR else 0.0
            continue
        # the whole curve scaled by k (:func:`_peaks`, 6 loads): w = Dα − k·P·tanh(Dα/P)
        w[i] = D[i] * alpha - k * peak[i] * t
        sech2 = 1.0 - t * t
        dw_a[i] = D[i] * (1.0 - k * sech2)
        dw_D[i] = alpha * (1.0 - k * sech2)
        dw_mu[i] = (k * dpeak[i] * (u * sech2 - t) - dpeak[2 + i] * peak[i] * t) if mu[i] > MU_FLOOR else 0.0
    return w, dw_a, dw_D, dw_mu


@cached_njit(fastmath=False)
def _rhs(x, th, mu, Fz, delta, V, kn, Dz_idx, Dz_scale, steer_cols, steer_g, n_aug):
    """ẋ, and when ``n_aug`` > 0: ∂ẋ/∂x (6, 6) and ∂ẋ/∂(constants) placed in the augmented state's columns
    (6, n_aug): the log-scale parameters (column Dz_idx[i], scale θ_i), μ per axle (columns Dz_idx[8],
    Dz_idx[9]; −1 for none), the extra states that shift the steering (steer_cols, by steer_g)."""
    l1, l2 = kn[_K_L1], kn[_K_L2]
    E, A = _linear_parts(th, V, kn)
    # the tyre correction w and its derivatives
    D = np.array([th[D1], th[D2]])
    peak = np.empty(4)
    dpeak = np.empty(4)
    _peaks(mu, Fz, peak, dpeak)
    w, dw_a, dw_D, dw_mu = _tyre_terms(x, D, peak, mu, dpeak)
    rhs = A @ x
    rhs[4] -= V * delta
    rhs[1] += l1 * w[0] - l2 * w[1]
    rhs[2] += w[0] + w[1]
    Einv = np.linalg.inv(E)
    f = Einv @ rhs
    if n_aug == 0:  # the mean alone
        return f, np.zeros((6, 6)), np.zeros((6, 1))
    Jx = A.copy()
    for i in range(2):
        Jx[1, A1 + i] += (l1 if i == 0 else -l2) * dw_a[i]
        Jx[2, A1 + i] += dw_a[i]
    Jx = Einv @ Jx
    Dz = np.zeros((6, n_aug))
    # ∂rhs/∂θ_i − ∂E/∂θ_i f, then E⁻¹, times θ_i (log scale)
    g = np.zeros(6)
    for p in range(N_PARAMS):
        col = Dz_idx[p]
        if col < 0:
            continue
        g[:] = 0.0
        if p == MZZ:
            g[1] = -f[R]
        elif p == MXX:
            g[0] = -f[P]
        elif p == B1:
            g[4] = -f[A1] if th[B1] > B_FLOOR else 0.0
        elif p == B2:
            g[5] = -f[A2] if th[B2] > B_FLOOR else 0.0
        elif p == D1 or p == D2:
            i = p - D1
            a = x[A1 + i]
            g[1] = (-l1 * a + l1 * dw_D[0]) if i == 0 else (l2 * a - l2 * dw_D[1])
            g[2] = -a + dw_D[i]
        elif p == ARO:
            g[0] = -x[P]
        elif p == KRO:
            g[0] = -x[PHI]
        Dz[:, col] += (Einv @ g) * (th[p] * Dz_scale[p])
    for i in range(2):
        col = Dz_idx[N_PARAMS + i]
        if col < 0:
            continue
        g[:] = 0.0
        g[1] = (l1 if i == 0 else -l2) * dw_mu[i]
        g[2] = dw_mu[i]
        Dz[:, col] += Einv @ g
    if steer_cols.shape[0]:
        bdelta = np.zeros(6)
        bdelta[4] = -V
        fd = Einv @ bdelta
        for j in range(steer_cols.shape[0]):
            Dz[:, steer_cols[j]] += fd * steer_g[j]
    return f, Jx, Dz


@cached_njit(fastmath=False)
def substeps(dt, V, th, kn):
    """RK4 sub-steps for a period ``dt`` at speed V: h·V/min(b) ≤ MAX_STIFF_STEP (accuracy on the tyre lag),
    and h·ρ ≤ MAX_STABLE_STEP with ρ the spectral radius of the linear part E⁻¹A (stability; the tanh only
    lowers the tyres' slope). ρ is bounded (:func:`spectral_radius_bound`, within 1 % above it) only when the
    cheap bound ‖E⁻¹A‖∞ ≥ ρ says it could bind: for parameter sets far from a car's (a UKF sigma point with a tiny
    Mzz and huge D, an unobserved roll stiffness drifted to 1e7 N·m/rad, a fit with no roll channel), whose
    explicit step would blow up; the count is then the exact ρ's or one more. At most MAX_SUBSTEPS."""
    return substeps_from(dt, V, th, _inverse_parts(th, V, kn)[1])


@cached_njit(fastmath=False)
def substeps_from(dt, V, th, EA):
    """:func:`substeps` from E⁻¹A (6, 6) already formed at (θ, V) (the passes form it once a sample for their
    stages: issue 40)."""
    n = dt * abs(V) / min(th[B1], th[B2]) / MAX_STIFF_STEP
    norm = 0.0
    for i in range(6):
        row = 0.0
        for j in range(6):
            row += abs(EA[i, j])
        norm = max(norm, row)
    if not norm < np.inf:
        return MAX_SUBSTEPS  # non-finite parameters: the step shows it, the filter's guards act
    if dt * norm / MAX_STABLE_STEP > max(n, 1.0):
        n = max(n, dt * spectral_radius_bound(EA, norm, max(n, 1.0) * MAX_STABLE_STEP / dt) / MAX_STABLE_STEP)
    if not n < MAX_SUBSTEPS:
        return MAX_SUBSTEPS
    return max(1, int(math.ceil(n)))


@cached_njit(fastmath=False)
def spectral_radius_bound(EA, norm, enough=0.0):
    """An upper bound on the spectral radius ρ of ``EA`` (6, 6) that converges to it: ρ ≤ ‖M^k‖^(1/k) for every k
    (Gelfand), here k = 2¹² by twelve squarings, each of the product normalised (its ∞-norm carried as a
    logarithm: no overflow or underflow whatever the scale); ``norm`` is ‖EA‖∞. Within a factor κ^(1/4096) of ρ
    (κ: the eigenvectors' condition number; 1.007 at κ = 1e12). :func:`substeps` takes it for ρ: a LAPACK
    eigen-decomposition (complex, ~30 µs) at every sample was all of a tyre pass's cost on the race car, whose
    ∞-norm bound binds everywhere (issue 40). Stops as soon as the bound is at most ``enough`` (a bound that no
    longer matters to the caller; 0: never)."""
    M = np.empty((6, 6))
    T = np.empty((6, 6))
    for i in range(6):
        for j in range(6):
            M[i, j] = EA[i, j] / norm
    log_c = math.log(norm)  # M^k = c · N, ‖N‖∞ = 1
    k = 1.0
    for _ in range(12):
        peak = 0.0
        for i in range(6):
            row = 0.0
            for j in range(6):
                acc = 0.0
                for m in range(6):
                    acc += M[i, m] * M[m, j]
                T[i, j] = acc
                row += abs(acc)
            peak = max(peak, row)
        if not peak > 0.0:  # N² = 0: M is nilpotent
            return 0.0
        for i in range(6):
            for j in range(6):
                M[i, j] = T[i, j] / peak
        log_c = 2.0 * log_c + math.log(peak)
        k *= 2.0
        if math.exp(log_c / k) <= enough:
            break
    return math.exp(log_c / k)


@cached_njit(fastmath=False)
def input_at(w, s, shift):
    """δ(s) + ``shift`` of a step's input ``w`` (4,) at normalised time ``s`` (0 at the step's start, 1 at its end):
    the arithmetic of :func:`online_id.model.intersample.value_at`. The hold's w = [δ, 0, 0, 0] gives δ + shift."""
    return (w[0] + s * (w[1] + s * (w[2] / 2.0 + s * w[3] / 6.0))) + shift


@cached_njit(fastmath=False)
def step_input(x, S, th, mu, Fz, w, shift, V, dt, kn, Dz_idx, Dz_scale, steer_cols, steer_g):
    """One sample period driven by the step's input ``w`` (4,) (the road-wheel angle's value and derivatives in
    normalised time, :mod:`online_id.model.intersample`) plus the extra states' steering ``shift`` [rad]: the state
    x (6,) and its sensitivity S (6, n_aug) to the augmented state at the block start advanced by RK4 (module
    docstring), sub-step i of n taking δ at s = (i + c)/n, c = 0, ½, ½, 1, of its stages. V held. Returns new
    (x, S). The arithmetic of :func:`_rhs` at each stage, with E⁻¹ and E⁻¹A formed once for the step and the
    stages by loops into buffers (:func:`_augmented_stage`; issue 40: numba's ``inv`` and small products at every
    stage were most of a tyre filter's time)."""
    th = floored(th)
    D = np.array([th[D1], th[D2]])
    peak = np.empty(4)
    dpeak = np.empty(4)
    _peaks(mu, Fz, peak, dpeak)
    x = x.copy()
    S = S.copy()
    m = S.shape[1]
    _step_into(x, S, np.empty((4, N_STATES)), np.empty((4, N_STATES, m)), np.empty(N_STATES), np.empty((N_STATES, m)),
               th, D, peak, mu, dpeak, w, shift, V, dt, kn, Dz_idx, Dz_scale, steer_cols, steer_g)
    return x, S


@cached_njit(fastmath=False)
def _step_into(x, S, F, K, xs, Ss, th, D, peak, mu, dpeak, w, shift, V, dt, kn, Dz_idx, Dz_scale, steer_cols,
               steer_g):  # pragma: no cover -- compiled
    """:func:`step_input`'s step in place on x (6,) and S (6, n_aug), through the buffers of :func:`_rk4_augmented`,
    θ already floored, ``D`` its cornering stiffnesses, ``peak`` and ``dpeak`` the loads' (:func:`_peaks`): a run of
    samples makes its buffers once (online_id/filters/tyre_block.py)."""
    Einv, EA = _inverse_parts(th, V, kn)
    n = substeps_from(dt, V, th, EA)
    _rk4_augmented(x, S, F, K, xs, Ss, False, EA, Einv, V, w, shift, n, dt / n, th, D, peak, mu, dpeak, Dz_idx,
                   Dz_scale, steer_cols, steer_g, kn[_K_L1], kn[_K_L2])


@cached_njit(fastmath=False)
def _rk4_augmented(x, S, F, K, xs, Ss, first_ready, EA, Einv, V, w, shift, n, h, th, D, peak, mu, dpeak, Dz_idx,
                   Dz_scale, steer_cols, steer_g, l1, l2):  # pragma: no cover -- compiled
    """x (6,) and S (6, n_aug) advanced in place by ``n`` RK4 sub-steps of ``h`` (:func:`step_input`'s, δ at the
    stages' times of the input ``w`` plus ``shift``), each stage by :func:`_augmented_stage`, through the buffers
    ``F`` (4, 6), ``K`` (4, 6, n_aug) (the four stages' ẋ and k), ``xs`` (6,) and ``Ss`` (6, n_aug) (a pass makes
    no array a sample). ``first_ready``: ``F[0]``, ``K[0]`` already hold the first sub-step's first stage (the
    polish's output took it)."""
    m = S.shape[1]
    f1, f2, f3, f4 = F[0], F[1], F[2], F[3]
    K1, K2, K3, K4 = K[0], K[1], K[2], K[3]
    d1 = input_at(w, 0.0, shift)
    for i in range(n):
        d0 = d1  # (the last stage's δ is the next sub-step's first)
        dm = input_at(w, (i + 0.5) / n, shift)
        d1 = input_at(w, (i + 1.0) / n, shift)
        if i > 0 or not first_ready:
            _augmented_stage(f1, K1, x, S, EA, Einv, V, d0, th, D, peak, mu, dpeak, Dz_idx, Dz_scale, steer_cols,
                             steer_g, l1, l2)
        _advance(xs, Ss, x, S, 0.5 * h, f1, K1)
        _augmented_stage(f2, K2, xs, Ss, EA, Einv, V, dm, th, D, peak, mu, dpeak, Dz_idx, Dz_scale, steer_cols,
                         steer_g, l1, l2)
        _advance(xs, Ss, x, S, 0.5 * h, f2, K2)
        _augmented_stage(f3, K3, xs, Ss, EA, Einv, V, dm, th, D, peak, mu, dpeak, Dz_idx, Dz_scale, steer_cols,
                         steer_g, l1, l2)
        _advance(xs, Ss, x, S, h, f3, K3)
        _augmented_stage(f4, K4, xs, Ss, EA, Einv, V, d1, th, D, peak, mu, dpeak, Dz_idx, Dz_scale, steer_cols,
                         steer_g, l1, l2)
        for a in range(N_STATES):
            x[a] = x[a] + h / 6.0 * (f1[a] + 2.0 * f2[a] + 2.0 * f3[a] + f4[a])
            for c in range(m):
                S[a, c] = S[a, c] + h / 6.0 * (K1[a, c] + 2.0 * K2[a, c] + 2.0 * K3[a, c] + K4[a, c])


@cached_njit(fastmath=False)
def _rk4_mean(x, EA, Einv, V, w, shift, n, h, D, peak, l1, l2, xs, f1, f2, f3, f4,
              first_ready=False):  # pragma: no cover -- compiled
    """x (6,) advanced in place by ``n`` RK4 sub-steps of ``h``, the mean alone (each stage by :func:`_rhs_into`,
    δ at the stages' times of the input ``w`` plus ``shift``), through the buffers ``xs``, ``f1`` … ``f4``;
    ``first_ready``: ``f1`` already holds the first stage (the caller's output at the sample took it)."""
    e4, g1, g2 = Einv[:, 4], Einv[:, 1], Einv[:, 2]
    u1 = -V * input_at(w, 0.0, shift)
    for i in range(n):
        u0 = u1
        um = -V * input_at(w, (i + 0.5) / n, shift)
        u1 = -V * input_at(w, (i + 1.0) / n, shift)
        if i > 0 or not first_ready:
            _rhs_into(f1, x, EA, e4, u0, g1, g2, D, peak, l1, l2)
        for a in range(N_STATES):
            xs[a] = x[a] + 0.5 * h * f1[a]
        _rhs_into(f2, xs, EA, e4, um, g1, g2, D, peak, l1, l2)
        for a in range(N_STATES):
            xs[a] = x[a] + 0.5 * h * f2[a]
        _rhs_into(f3, xs, EA, e4, um, g1, g2, D, peak, l1, l2)
        for a in range(N_STATES):
            xs[a] = x[a] + h * f3[a]
        _rhs_into(f4, xs, EA, e4, u1, g1, g2, D, peak, l1, l2)
        for a in range(N_STATES):
            x[a] = x[a] + h / 6.0 * (f1[a] + 2.0 * f2[a] + 2.0 * f3[a] + f4[a])


@cached_njit(fastmath=False)
def _augmented_stage(f, K, x, S, EA, Einv, V, delta, th, D, peak, mu, dpeak, Dz_idx, Dz_scale, steer_cols, steer_g,
                     l1, l2):  # pragma: no cover -- compiled
    """One RK4 stage of :func:`step_input`: ẋ into ``f`` (6,) and K = ∂ẋ/∂x S + ∂ẋ/∂(augmented state) into ``K``
    (6, n_aug), the arithmetic of :func:`_rhs` (the columns ``Dz_idx``, ``Dz_scale``, ``steer_cols``, ``steer_g``
    as there; E⁻¹ and E⁻¹A given) by loops."""
    w, dw_a, dw_D, dw_mu = _tyre_terms(x, D, peak, mu, dpeak)
    t1 = l1 * w[0] - l2 * w[1]
    t2 = w[0] + w[1]
    u = -V * delta
    for a in range(N_STATES):
        acc = 0.0
        for b in range(N_STATES):
            acc += EA[a, b] * x[b]
        f[a] = acc + Einv[a, 4] * u + Einv[a, 1] * t1 + Einv[a, 2] * t2
    m = S.shape[1]
    for a in range(N_STATES):
        g1, g2 = Einv[a, 1], Einv[a, 2]
        j1 = EA[a, A1] + g1 * l1 * dw_a[0] + g2 * dw_a[0]
        j2 = EA[a, A2] - g1 * l2 * dw_a[1] + g2 * dw_a[1]
        # row a of ∂ẋ/∂x times S, its terms summed in state order (r, β, φ, p, α1, α2) as a loop over them would:
        # one straight line a column, no branch inside the loop over the columns
        e_r, e_beta, e_phi, e_p = EA[a, R], EA[a, BETA], EA[a, PHI], EA[a, P]
        for c in range(m):
            K[a, c] = (((((0.0 + e_r * S[R, c]) + e_beta * S[BETA, c]) + e_phi * S[PHI, c]) + e_p * S[P, c])
                       + j1 * S[A1, c]) + j2 * S[A2, c]
        for p in range(N_PARAMS):
            col = Dz_idx[p]
            if col < 0:
                continue
            if p == MZZ:
                v = -f[R] * g1
            elif p == MXX:
                v = -f[P] * Einv[a, 0]
            elif p == B1:
                v = -f[A1] * Einv[a, 4] if th[B1] > B_FLOOR else 0.0
            elif p == B2:
                v = -f[A2] * Einv[a, 5] if th[B2] > B_FLOOR else 0.0
            elif p == D1:
                v = g1 * l1 * (dw_D[0] - x[A1]) + g2 * (dw_D[0] - x[A1])
            elif p == D2:
                v = -g1 * l2 * (dw_D[1] - x[A2]) + g2 * (dw_D[1] - x[A2])
            elif p == ARO:
                v = -x[P] * Einv[a, 0]
            else:  # KRO
                v = -x[PHI] * Einv[a, 0]
            K[a, col] += v * (th[p] * Dz_scale[p])
        for i in range(2):
            col = Dz_idx[N_PARAMS + i]
            if col < 0:
                continue
            K[a, col] += (g1 * l1 if i == 0 else -g1 * l2) * dw_mu[i] + g2 * dw_mu[i]
        for j in range(steer_cols.shape[0]):
            K[a, steer_cols[j]] += -V * Einv[a, 4] * steer_g[j]


@cached_njit(fastmath=False)
def step(x, S, th, mu, Fz, delta, V, dt, kn, Dz_idx, Dz_scale, steer_cols, steer_g):
    """One sample period with δ held (:func:`step_input` of the hold's input [δ, 0, 0, 0]). Returns new (x, S)."""
    w = np.zeros(4)
    w[0] = delta
    return step_input(x, S, th, mu, Fz, w, 0.0, V, dt, kn, Dz_idx, Dz_scale, steer_cols, steer_g)


@cached_njit(fastmath=False)
def output(x, S, th, mu, Fz, delta, V, kn, Dz_idx, Dz_scale, steer_cols, steer_g):
    """Outputs y = [r, φ, p, a_y, β] (5,), their sensitivity to the block-start augmented state (5, n_aug)
    through S and directly, and ∂y/∂x (5, 6). a_y = V (β̇ + r); the lateral velocity per unit speed, the sideslip
    angle β (the filters' form, model/lateral.py VY: a batch caller multiplies row 4 by V).

    The arithmetic of a pass's output (:func:`simulate_blocks_input`): E⁻¹ and E⁻¹A by cofactors
    (:func:`_inverse_parts`), β̇ and its sensitivity K = ∂ẋ/∂x·S + ∂ẋ/∂(augmented state) by :func:`_augmented_stage`'s
    loops, where a LAPACK inverse and a dozen small matrix products ran at every observed sample (issue 40: most of
    the tyre EKF's compiled time at 1 kHz)."""
    th = floored(th)
    D = np.array([th[D1], th[D2]])
    peak = np.empty(4)
    dpeak = np.empty(4)
    _peaks(mu, Fz, peak, dpeak)
    want = S.shape[1]
    y = np.empty(5)
    H = np.empty((5, want))
    C = np.empty((5, 6))
    _output_into(y, H, C, np.empty(N_STATES), np.empty((N_STATES, want)), x, S, th, mu, delta, V, kn, Dz_idx,
                 Dz_scale, steer_cols, steer_g, D, peak, dpeak)
    return y, H, C


@cached_njit(fastmath=False)
def _output_into(y, H, C, f, K, x, S, th, mu, delta, V, kn, Dz_idx, Dz_scale, steer_cols, steer_g, D, peak,
                 dpeak):  # pragma: no cover -- compiled
    """:func:`output`'s arithmetic into the buffers ``y`` (5,), ``H`` (5, n_aug), ``C`` (5, 6), through ``f`` (6,)
    and ``K`` (6, n_aug), θ already floored, ``D`` its cornering stiffnesses and ``peak``, ``dpeak`` the loads'
    (:func:`_peaks`): a run of samples makes its buffers once (online_id/filters/tyre_block.py)."""
    Einv, EA = _inverse_parts(th, V, kn)
    l1, l2 = kn[_K_L1], kn[_K_L2]
    _augmented_stage(f, K, x, S, EA, Einv, V, delta, th, D, peak, mu, dpeak, Dz_idx, Dz_scale, steer_cols, steer_g,
                     l1, l2)
    y[0] = x[R]
    y[1] = x[PHI]
    y[2] = x[P]
    y[3] = V * (f[BETA] + x[R])
    y[4] = x[BETA]
    # ∂β̇/∂x: E⁻¹A's row, the tyres' slopes in the slip angles' columns (as _augmented_stage's j1, j2)
    _, dw_a, _, _ = _tyre_terms(x, D, peak, mu, dpeak)
    g1, g2 = Einv[BETA, 1], Einv[BETA, 2]
    for i in range(5):
        for j in range(6):
            C[i, j] = 0.0
    C[0, R] = 1.0
    C[1, PHI] = 1.0
    C[2, P] = 1.0
    C[4, BETA] = 1.0
    for j in range(6):
        C[3, j] = V * EA[BETA, j]
    C[3, A1] = V * (EA[BETA, A1] + g1 * l1 * dw_a[0] + g2 * dw_a[0])
    C[3, A2] = V * (EA[BETA, A2] - g1 * l2 * dw_a[1] + g2 * dw_a[1])
    C[3, R] += V
    for j in range(H.shape[1]):
        H[0, j] = S[R, j]
        H[1, j] = S[PHI, j]
        H[2, j] = S[P, j]
        H[3, j] = V * (K[BETA, j] + S[R, j])
        H[4, j] = S[BETA, j]


@cached_njit(fastmath=False)
def step_points_input(X, thetas, mus, Fz, w, shifts, V, dt, kn):
    """The mean map alone for many points (the UKF's sigma points): X (S, 6), θ (S, 8), μ (S, 2), the step's
    input ``w`` (4,) and each point's steering shift (S,) (:func:`step_input`'s stages; E⁻¹A and E⁻¹'s columns
    once a point, the stages by :func:`_rhs_into`: issue 40, the UKF with tyres at 10× the linear UKF). Returns
    the stepped points: :func:`points_parts`, then :func:`advance_points`."""
    parts = points_parts(X.shape[0])
    floor_points(thetas, parts[0])
    step_parts(parts, mus, Fz, V, dt, kn, True, True)
    out = X.copy()
    advance_points(out, parts, w, shifts, V, dt, kn)
    return out


@cached_njit(fastmath=False)
def points_parts(n_points):
    """What a step of many points takes from each point's θ, μ, the loads, the period and the speed, unfilled:
    (θ floored (S, 8), sub-step counts (S,), E⁻¹ (S, 6, 6), E⁻¹A (S, 6, 6), peaks and curve scales (S, 4) and their
    μ-derivatives (S, 4): :func:`_peaks`); a caller that steps the same points through several samples keeps them
    while their inputs repeat (filters/tyre_block.py ``sigma_tyre_pass``)."""
    return (np.empty((n_points, N_PARAMS)), np.ones(n_points, dtype=np.int64),
            np.empty((n_points, N_STATES, N_STATES)), np.empty((n_points, N_STATES, N_STATES)),
            np.empty((n_points, 4)), np.empty((n_points, 4)))


@cached_njit(fastmath=False)
def floor_points(thetas, ths):
    """``ths`` (S, 8) ← each point's θ as the model uses it (:func:`floored`)."""
    for p in range(thetas.shape[0]):
        ths[p] = floored(thetas[p])


@cached_njit(fastmath=False)
def step_parts(parts, mus, Fz, V, dt, kn, new_step, new_loads):
    """Fill :func:`points_parts`' arrays in place: where ``new_step`` each point's sub-step count, E⁻¹ and E⁻¹A at
    the period ``dt`` and speed V, where ``new_loads`` its peaks and curve scales at μ (S, 4) and the loads ``Fz``."""
    ths, subs, Einvs, EAs, peaks, dpeaks = parts
    for p in range(ths.shape[0]):
        if new_step:
            Einvs[p], EAs[p] = _inverse_parts(ths[p], V, kn)
            subs[p] = substeps_from(dt, V, ths[p], EAs[p])
        if new_loads:
            _peaks(mus[p], Fz, peaks[p], dpeaks[p])


@cached_njit(fastmath=False)
def advance_points(X, parts, w, shifts, V, dt, kn):
    """X (S, 6) advanced in place through one period ``dt`` of input ``w`` (4,) plus each point's ``shifts``, with the
    points' :func:`step_parts` (RK4 by :func:`_rk4_mean`)."""
    ths, subs, Einvs, EAs, peaks, _ = parts
    l1, l2 = kn[_K_L1], kn[_K_L2]
    D = np.empty(2)
    x = np.empty(N_STATES)
    xs = np.empty(N_STATES)
    f1 = np.empty(N_STATES)
    f2 = np.empty(N_STATES)
    f3 = np.empty(N_STATES)
    f4 = np.empty(N_STATES)
    for s in range(X.shape[0]):
        D[0] = ths[s, D1]
        D[1] = ths[s, D2]
        for a in range(N_STATES):
            x[a] = X[s, a]
        n = subs[s]
        _rk4_mean(x, EAs[s], Einvs[s], V, w, shifts[s], n, dt / n, D, peaks[s], l1, l2, xs, f1, f2, f3, f4)
        for a in range(N_STATES):
            X[s, a] = x[a]


@cached_njit(fastmath=False)
def step_points(X, thetas, mus, Fz, deltas, V, dt, kn):
    """The mean map alone for many points, δ (S,) held: :func:`step_points_input` of the input 0 shifted by δ."""
    return step_points_input(X, thetas, mus, Fz, np.zeros(4), deltas, V, dt, kn)


@cached_njit(fastmath=False)
def output_points(X, thetas, mus, Fz, deltas, V, kn):
    """Outputs (S, 5) of many points (the lateral velocity per unit speed: :func:`output`)."""
    Y = np.empty((X.shape[0], 5))
    idx = -np.ones(N_PARAMS + 2, dtype=np.int64)
    scale = np.ones(N_PARAMS)
    none_i = np.zeros(0, dtype=np.int64)
    none_f = np.zeros(0)
    for s in range(X.shape[0]):
        f = _rhs(X[s], floored(thetas[s]), mus[s], Fz, deltas[s], V, kn, idx, scale, none_i, none_f, 0)[0]
        Y[s, 0] = X[s, R]
        Y[s, 1] = X[s, PHI]
        Y[s, 2] = X[s, P]
        Y[s, 3] = V * (f[BETA] + X[s, R])
        Y[s, 4] = X[s, BETA]
    return Y


@cached_njit(fastmath=False, nogil=True)
def simulate_blocks(theta, mu, Fz, deltas, speeds, dt, kn, q, mu_columns):
    """:func:`simulate_blocks_input` with the steering δ [rad] held over each sample period (the hold's step
    inputs [δ, 0, 0, 0], which :func:`step_input` steps as :func:`step` does, bit for bit)."""
    W = np.zeros((deltas.shape[0], 4))
    for k in range(deltas.shape[0]):
        W[k, 0] = deltas[k]
    return simulate_blocks_input(theta, mu, _static_loads(Fz, deltas.shape[0]), W, speeds, dt, kn, q, mu_columns)


@cached_njit(fastmath=False, nogil=True)
def simulate_blocks_input(theta, mu, Fz, W, speeds, dt, kn, q, mu_columns, shift=0.0, shift_column=False):
    """A whole run from rest, with the outputs' exact sensitivities: block means of q samples of the outputs
    (n_blocks, 5) and of their derivatives (n_blocks, 5, 8 + mu_columns) with respect to the 8 log-scale
    parameters and μ (one column for both axles, or one per axle with ``mu_columns`` 2), the axle loads ``Fz`` (n, 2)
    [N] each sample's (held over its step: braking and traction move them,
    :func:`online_id.vehicle.parameters.axle_loads_at`). Each sample's step is
    driven by its input polynomial ``W`` (n, 4) (the road-wheel angle's value and derivatives in normalised time,
    :func:`online_id.sim.block_means.step_inputs`): the RK4 stages take δ where the curve is (:func:`step_input`); the
    speed V is held over each step; the outputs are taken at each sample, at its own δ W[k, 0], before its step.
    The batch polish's model with tyres (online_id/batchfit/polish.py). ``shift`` [rad] is added to the road-wheel
    angle throughout (a steering offset beside the tyres); with ``shift_column`` the derivatives' last column is
    with respect to it (n_par = 8 + ``mu_columns`` + 1).

    The arithmetic of :func:`output` and :func:`step_input` (the filters'), arranged for a pass of a whole run:
    E⁻¹ and E⁻¹A once a sample (not at every stage), the stages into buffers by loops (no BLAS call and no array
    made per stage; :func:`_augmented_stage`), the output's evaluation reused as the first stage. A pass of the
    race log 10-20 s → well under a second (issue 40: the tyre polish's 26 passes were 95 s); the same numbers to
    round-off (``tests/test_model.py``)."""
    n_par = N_PARAMS + mu_columns + (1 if shift_column else 0)
    Y, dY, _, _, _, _ = blocks_from(theta, mu, Fz, W, speeds, dt, kn, q, mu_columns, shift, shift_column,
                                    np.zeros(N_STATES), np.zeros((N_STATES, n_par)), np.zeros(0, dtype=np.int64),
                                    W.shape[0] // q)
    return Y, dY


@cached_njit(fastmath=False, nogil=True)
def blocks_from(theta, mu, Fz, W, speeds, dt, kn, q, mu_columns, shift, shift_column, x0, S0, marks, n_blocks):
    """:func:`simulate_blocks_input` from the state ``x0`` (6,) and its sensitivities ``S0`` (6, n_par) at the first
    sample instead of rest (a piece of a run, :mod:`online_id.model.pieces`). Returns the block means and their
    derivatives, the states (m, 6) and sensitivities (m, 6, n_par) at the samples ``marks`` (m,) (each before its
    output; zeros for a mark not in the blocks), and those after the last block's step. ``n_blocks`` blocks of ``q``
    samples (the arrays may go on: a piece's last step takes the loads of the sample after it, as the whole pass's
    does)."""
    theta = floored(theta)
    # the sensitivities kept: the parameters, μ and the steering shift (from rest ∂x/∂x0 is 0)
    n_par = N_PARAMS + mu_columns + (1 if shift_column else 0)
    l1, l2 = kn[_K_L1], kn[_K_L2]
    D = np.array([theta[D1], theta[D2]])
    peak = np.empty(4)
    dpeak = np.empty(4)
    # the augmented state's columns as _augmented_stage takes them: the 8, then μ (one column or one an axle)
    cols = np.empty(N_PARAMS + 2, dtype=np.int64)
    for p in range(N_PARAMS):
        cols[p] = p
    cols[N_PARAMS] = N_PARAMS
    cols[N_PARAMS + 1] = N_PARAMS + (1 if mu_columns == 2 else 0)
    scale = np.ones(N_PARAMS)
    steer_cols = np.full(1 if shift_column else 0, n_par - 1, dtype=np.int64)
    steer_g = np.ones(1 if shift_column else 0)
    x = x0.copy()
    S = S0.copy()
    x_marks = np.zeros((marks.shape[0], N_STATES))
    S_marks = np.zeros((marks.shape[0], N_STATES, n_par))
    at = 0  # the next mark
    F = np.empty((4, N_STATES))  # the RK4 stages' buffers (_rk4_augmented), F[0] and K[0] the output's too
    K = np.empty((4, N_STATES, n_par))
    xs = np.empty(N_STATES)
    Ss = np.empty((N_STATES, n_par))
    f1, K1 = F[0], K[0]
    Y = np.zeros((n_blocks, 5))
    dY = np.zeros((n_blocks, 5, n_par))
    mid = np.empty(Fz.shape[1])
    for b in range(n_blocks):
        for j in range(q):
            k = b * q + j
            while at < marks.shape[0] and marks[at] < k:
                at += 1
            if at < marks.shape[0] and marks[at] == k:
                x_marks[at] = x
                S_marks[at] = S
            V = speeds[k]
            Einv, EA = _inverse_parts(theta, V, kn)
            sub = substeps_from(dt, V, theta, EA)
            w = W[k]
            _peaks(mu, Fz[k], peak, dpeak)
            # the output at the sample (its δ W[k, 0]): the first stage's ẋ and k = J S + Z
            _augmented_stage(f1, K1, x, S, EA, Einv, V, input_at(w, 0.0, shift), theta, D, peak, mu, dpeak, cols,
                             scale, steer_cols, steer_g, l1, l2)
            Y[b, 0] += x[R] / q
            Y[b, 1] += x[PHI] / q
            Y[b, 2] += x[P] / q
            Y[b, 3] += V * (f1[BETA] + x[R]) / q
            Y[b, 4] += V * x[BETA] / q
            for c in range(n_par):
                dY[b, 0, c] += S[R, c] / q
                dY[b, 1, c] += S[PHI, c] / q
                dY[b, 2, c] += S[P, c] / q
                dY[b, 3, c] += V * (K1[BETA, c] + S[R, c]) / q
                dY[b, 4, c] += V * S[BETA, c] / q
            moved = k + 1 < W.shape[0] and _step_loads(Fz, k, mid)
            if moved:  # loads that move: the step takes their midpoint (its first stage then anew)
                _peaks(mu, mid, peak, dpeak)
            _rk4_augmented(x, S, F, K, xs, Ss, not moved, EA, Einv, V, w, shift, sub, dt / sub, theta, D, peak, mu,
                           dpeak, cols, scale, steer_cols, steer_g, l1, l2)
    return Y, dY, x_marks, S_marks, x, S


@cached_njit(fastmath=False)
def _advance(xs, Ss, x, S, h, f, K):  # pragma: no cover -- compiled
    """xs = x + h f, Ss = S + h K (an RK4 stage's point), into the buffers."""
    for a in range(N_STATES):
        xs[a] = x[a] + h * f[a]
        for c in range(S.shape[1]):
            Ss[a, c] = S[a, c] + h * K[a, c]


@cached_njit(fastmath=False, nogil=True)
def rk4_states_and_outputs(theta, mu, Fz, deltas, speeds, dt, kn):
    """A whole run from rest: the states (N, 6) and outputs (N, 5) [r, φ, p, a_y, v_y] at each sample, by the same
    RK4 as :func:`step` (δ and V held over each period, the same sub-steps), the mean alone: the batch fits' model
    with tyres (:func:`online_id.sim.with_effects.predict` with ``method="rk4"``). :func:`rk4_states_and_outputs_input`
    of the hold's step inputs [δ, 0, 0, 0] (the same numbers, bit for bit)."""
    W = np.zeros((deltas.shape[0], 4))
    for k in range(deltas.shape[0]):
        W[k, 0] = deltas[k]
    return rk4_states_and_outputs_input(theta, mu, _static_loads(Fz, deltas.shape[0]), W, speeds, dt, kn)


@cached_njit(fastmath=False, nogil=True)
def rk4_states_and_outputs_input(theta, mu, Fz, W, speeds, dt, kn):
    """:func:`rk4_states_and_outputs` with each sample's step driven by its input polynomial ``W`` (n, 4) (the
    road-wheel angle's value and derivatives in normalised time, :func:`online_id.sim.block_means.step_inputs`): the
    RK4 stages take δ where the curve is, as :func:`step_input` does; V held over each step at ``speeds[k]``; the
    outputs at each sample at its own δ W[k, 0]; the axle loads ``Fz`` (n, ·) [N] each sample's, the step into the
    next sample taking the two samples' mean (:func:`_step_loads`, as the filters do).
    E⁻¹A and E⁻¹'s columns are formed once a sample (a few µs a
    sample). The mean alone: the batch fits' and the diagnosis's model with tyres (the hold's too,
    :func:`rk4_states_and_outputs`) (issue 40: the fixed point it replaces fell back, at the
    race car's 1.7 g, to a per-sample Python loop)."""
    return states_and_outputs_from(theta, mu, Fz, W, speeds, dt, kn, np.zeros(N_STATES))


@cached_njit(fastmath=False, nogil=True)
def states_and_outputs_from(theta, mu, Fz, W, speeds, dt, kn, x0):
    """:func:`rk4_states_and_outputs_input` from the state ``x0`` (6,) at the first sample instead of rest (a piece
    of a run, :mod:`online_id.model.pieces`)."""
    theta = floored(theta)
    n = W.shape[0]
    l1, l2 = kn[_K_L1], kn[_K_L2]
    peak = np.empty(4)
    dpeak = np.empty(4)
    D = np.array([theta[D1], theta[D2]])
    states = np.zeros((n, N_STATES))
    Y = np.zeros((n, 5))
    x = x0.copy()
    # the stages' buffers (no array is made inside the loop: issue 40, a race log's pass is 40,000 samples)
    xs = np.empty(N_STATES)
    f1 = np.empty(N_STATES)
    f2 = np.empty(N_STATES)
    f3 = np.empty(N_STATES)
    f4 = np.empty(N_STATES)
    mid = np.empty(Fz.shape[1])
    for k in range(n):
        V = speeds[k]
        Einv, EA = _inverse_parts(theta, V, kn)
        sub = substeps_from(dt, V, theta, EA)
        states[k] = x
        w = W[k]
        _peaks(mu, Fz[k], peak, dpeak)
        _rhs_into(f1, x, EA, Einv[:, 4], -V * w[0], Einv[:, 1], Einv[:, 2], D, peak, l1, l2)
        Y[k, 0] = x[R]
        Y[k, 1] = x[PHI]
        Y[k, 2] = x[P]
        Y[k, 3] = V * (f1[BETA] + x[R])
        Y[k, 4] = V * x[BETA]
        moved = k + 1 < n and _step_loads(Fz, k, mid)
        if moved:  # loads that move: the step takes their midpoint
            _peaks(mu, mid, peak, dpeak)
        # (E⁻¹B δ at the stages = E⁻¹[:, 4] u; the hold's input_at is δ itself: the output's stage is the step's first
        # where the loads held, the same numbers)
        _rk4_mean(x, EA, Einv, V, w, 0.0, sub, dt / sub, D, peak, l1, l2, xs, f1, f2, f3, f4, not moved)
    return states, Y


@cached_njit(fastmath=False)
def _rhs_into(out, x, EA, e4, u, g1, g2, D, peak, l1, l2):  # pragma: no cover -- compiled
    """ẋ = E⁻¹A x + E⁻¹B δ + E⁻¹G w(α) into ``out`` (6,), with E⁻¹B δ = e4·u and E⁻¹'s yaw and lateral columns
    ``g1``, ``g2`` given: loops, no array made (the RK4 pass's stages)."""
    t0 = math.tanh(D[0] * x[A1] / peak[0])
    t1 = math.tanh(D[1] * x[A2] / peak[1])
    if peak[2] != 1.0 or peak[3] != 1.0:  # the whole curve scaled (:func:`_peaks`, 6 loads)
        w0 = D[0] * x[A1] - peak[2] * peak[0] * t0
        w1 = D[1] * x[A2] - peak[3] * peak[1] * t1
    else:
        w0 = D[0] * x[A1] - peak[0] * t0
        w1 = D[1] * x[A2] - peak[1] * t1
    t1 = l1 * w0 - l2 * w1
    t2 = w0 + w1
    for a in range(N_STATES):
        acc = 0.0
        for b in range(N_STATES):
            acc += EA[a, b] * x[b]
        out[a] = acc + e4[a] * u + g1[a] * t1 + g2[a] * t2


@cached_njit(fastmath=False)
def total_substeps(theta, speeds, dt, kn):
    """RK4 sub-steps of one pass over a run at ``speeds`` (what a pass of :func:`simulate_blocks` will cost)."""
    theta = floored(theta)
    total = 0
    for k in range(speeds.shape[0]):
        total += substeps(dt, speeds[k], theta, kn)
    return total
