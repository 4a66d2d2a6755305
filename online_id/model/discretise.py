"""Exact zero-order-hold discretisation of the lateral model, and its parameter sensitivity.

For a sample period dt with δ held constant over the period,

    x[k+1] = Ad x[k] + Bd δ[k],   [[Ad, Bd], [0, 1]] = expm([[Ac, Bc], [0, 0]] dt).

The derivative of the transition with respect to θ_i uses Van Loan's block
identity: the top-right block of expm([[G, dG_i], [0, G]]) is the Fréchet
derivative of expm at G in the direction dG_i, exact up to round-off.

:class:`SpectralForm` gives the same from one eigen-decomposition for any period, and
(:meth:`SpectralForm.input_table`) the columns Γ_k = [φ_k(G dt)]_{0:6, 6} of an input polynomial between
samples (:mod:`online_id.model.intersample`: x(T) = Ad x + Σ_k Γ_k w_k, Γ_0 = Bd) with their first-order terms.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property, lru_cache

import numpy as np
from scipy.linalg import expm, lapack

from online_id.model import compiled
from online_id.model.lateral import (
    N_PARAMS,
    N_STATES,
    continuous_matrices,
    continuous_parameter_derivatives,
    descriptor_matrices,
    descriptor_parameter_derivatives,
    outputs_from_continuous,
)
from online_id.vehicle.parameters import KnownParameters


def _augmented(Ac, Bc, dt):
    n = N_STATES
    G = np.zeros(Ac.shape[:-2] + (n + 1, n + 1))
    G[..., :n, :n] = Ac * dt
    G[..., :n, n] = Bc * dt
    return G


def discretise(theta, speed, known: KnownParameters, dt: float):
    """Ad (shape (..., 6, 6)) and Bd (shape (..., 6)) for sample period ``dt`` [s]."""
    Ac, Bc = continuous_matrices(theta, speed, known)
    return discretise_continuous(Ac, Bc, dt)


def discretise_continuous(Ac, Bc, dt: float):
    """ZOH discretisation of given continuous matrices (batched over leading axes)."""
    Phi = expm(_augmented(Ac, Bc, dt))
    return Phi[..., :N_STATES, :N_STATES], Phi[..., :N_STATES, N_STATES]


@dataclass(frozen=True)
class Linearisation:
    """Everything a filter needs about the model at one parameter set, speed and sample period.

    Continuous: Ac (6, 6), Bc (6,), dAc (8, 6, 6), dBc (8, 6) (derivatives with respect to θ).
    Discrete (ZOH over ``dt``): Ad, Bd, dAd, dBd, same shapes.
    Outputs y = C x + D δ: C (4, 6), D (4,).
    """

    theta: np.ndarray
    speed: float
    dt: float
    Ac: np.ndarray
    Bc: np.ndarray
    dAc: np.ndarray
    dBc: np.ndarray
    Ad: np.ndarray
    Bd: np.ndarray
    dAd: np.ndarray
    dBd: np.ndarray
    C: np.ndarray
    D: np.ndarray


def linearise(theta, speed: float, known: KnownParameters, dt: float) -> Linearisation:
    """Continuous and discrete matrices with their θ-derivatives for one parameter set and speed."""
    Ac, Bc, dAc, dBc = continuous_parameter_derivatives(theta, speed, known)
    if Ac.ndim != 2:
        raise ValueError("linearise takes one parameter set and one speed")
    n = N_STATES + 1
    G = _augmented(Ac, Bc, dt)
    dG = _augmented(dAc, dBc, dt)  # (8, 7, 7)
    big = np.zeros((dG.shape[0], 2 * n, 2 * n))
    big[:, :n, :n] = G
    big[:, n:, n:] = G
    big[:, :n, n:] = dG
    Phi = expm(big)
    dPhi = Phi[:, :n, n:]
    Phi0 = Phi[0, :n, :n]
    C, D = outputs_from_continuous(Ac, Bc, np.asarray(speed, dtype=float), per_unit_speed=True)
    return Linearisation(
        theta=np.array(theta.to_vector() if hasattr(theta, "to_vector") else theta, dtype=float),
        speed=float(speed), dt=float(dt), Ac=Ac, Bc=Bc, dAc=dAc, dBc=dBc,
        Ad=Phi0[:N_STATES, :N_STATES], Bd=Phi0[:N_STATES, N_STATES],
        dAd=dPhi[:, :N_STATES, :N_STATES], dBd=dPhi[:, :N_STATES, N_STATES], C=C, D=D,
    )


def discretise_with_sensitivity(theta, speed, known: KnownParameters, dt: float):
    """Ad, Bd and their derivatives with respect to θ, for one parameter set and speed.

    Returns ``(Ad, Bd, dAd, dBd)`` with shapes (6, 6), (6,), (8, 6, 6), (8, 6):
    dAd[i] = ∂Ad/∂θ_i, dBd[i] = ∂Bd/∂θ_i.
    """
    lin = linearise(theta, speed, known, dt)
    return lin.Ad, lin.Bd, lin.dAd, lin.dBd


# -- many sample periods and speeds from one eigen-decomposition ----------------------------------------

#: Above this 1-norm condition number of the eigenvector matrix, :func:`spectral_form` reports the
#: decomposition unusable (round-off in Φ grows like cond · 1e-16, so 1e6 keeps it under ~1e-10). The
#: eigenvectors only become that ill-conditioned within ~1e-12 of a coalescing eigenvalue pair; over 3000
#: random parameter sets (prior · e^N(0,1)) and speeds of 3-80 m/s the largest seen was 2e4.
SPECTRAL_CONDITION_LIMIT = 1e6

#: Eigenvalue pairs with |(λa − λb) dt| below this get their divided difference from a series.
DIVIDED_DIFFERENCE_CLOSE = 1e-3
#: That series: φ1(z) = (e^z − 1)/z = 1 + z (1/2 + z (1/6 + z (1/24 + z/120))) + O(z⁵), its coefficients.
PHI1_SERIES = (1 / 2, 1 / 6, 1 / 24, 1 / 120)


def _cmatmul(a, b):
    """a @ b by real products: numpy's batched complex matmul runs a generic loop about 50x slower than
    the real one at these sizes."""
    ar, ai, br, bi = np.real(a), np.imag(a), np.real(b), np.imag(b)
    return (ar @ br - ai @ bi) + 1j * (ar @ bi + ai @ br)


def _real_of_product(a, b):
    """Re(a @ b) by real products."""
    return np.real(a) @ np.real(b) - np.imag(a) @ np.imag(b)


def continuous_speed_derivatives(theta, speed: float, known: KnownParameters):
    """∂Ac/∂V (shape (..., 6, 6)) and ∂Bc/∂V (shape (..., 6)), with Ac and Bc, for parameter sets
    ``theta`` (..., 8) at one speed.

    E, A and B are affine in V (and θ), so from E Ac = A: ∂Ac/∂V = E⁻¹ (∂A/∂V − ∂E/∂V Ac), likewise
    for Bc. Returns ``(Ac, Bc, dAc_dV, dBc_dV)``.
    """
    E0, A0, E_V, A_V, B_V, dE, dA = _affine_descriptor(known)
    theta = np.asarray(theta, dtype=float)
    Einv = np.linalg.inv(E0 + speed * E_V + np.tensordot(theta, dE, axes=1))
    Ac = Einv @ (A0 + speed * A_V + np.tensordot(theta, dA, axes=1))
    Bc = Einv @ (speed * B_V)
    dAc = Einv @ (A_V - E_V @ Ac)
    dBc = np.einsum("...ij,...j->...i", Einv, B_V - Bc @ E_V.T)
    return Ac, Bc, dAc, dBc


def speed_generators(thetas, speed: float, known: KnownParameters):
    """G = [[Ac, Bc], [0, 0]] (S, 7, 7) and its V-derivative [[∂Ac/∂V, ∂Bc/∂V], [0, 0]] (S, 7, 7) of parameter
    sets ``thetas`` (S, 8) at one speed: :func:`continuous_speed_derivatives` laid out as generators, in one
    compiled call (:func:`online_id.model.compiled.speed_generators`; the same to round-off)."""
    E0, A0, E_V, A_V, B_V, dE_flat, dA_flat, *_ = _affine_coefficients(known)
    thetas = np.ascontiguousarray(thetas, dtype=float)
    n = N_STATES + 1
    G, dG = np.empty((len(thetas), n, n)), np.empty((len(thetas), n, n))
    try:
        compiled.speed_generators(E0, A0, E_V, A_V, B_V, dE_flat, dA_flat, thetas, float(speed), G, dG)
    except np.linalg.LinAlgError as exc:
        raise np.linalg.LinAlgError(f"singular matrix E of the descriptor model ({exc})") from None
    return G, dG


@lru_cache(maxsize=16)
def _affine_descriptor(known: KnownParameters):
    """E, A, B of E ẋ = A x + B δ are affine in V and θ: their constant parts, V-coefficients and
    θ-coefficients (read off :func:`~online_id.model.lateral.descriptor_matrices` at V = 0, 1 and
    unit θ, exact)."""
    zero = np.zeros(N_PARAMS)
    E0, A0, B0 = descriptor_matrices(zero, 0.0, known)
    E1, A1, B1 = descriptor_matrices(zero, 1.0, known)
    dE, dA = descriptor_parameter_derivatives(known)
    return E0, A0, E1 - E0, A1 - A0, B1 - B0, dE, dA


@lru_cache(maxsize=16)
def _affine_coefficients(known: KnownParameters):
    """:func:`_affine_descriptor` laid out for one-parameter-set evaluation: θ-coefficients of E and A
    flattened to (8, 36); [∂A/∂θ, ∂B/∂θ] row-major (6, 8, 7) (the layout of :func:`derivative_blocks`'
    right-hand sides); ∂E/∂θ stacked the same way as one (6 · 8, 6) matrix; [∂A/∂V, ∂B/∂V] (6, 7)."""
    E0, A0, E_V, A_V, B_V, dE, dA = _affine_descriptor(known)
    P, n = dA.shape[0], dA.shape[1]
    dAB_rows = np.zeros((n, P, n + 1))  # [∂A/∂θ_i, ∂B/∂θ_i = 0], row-major
    dAB_rows[:, :, :n] = dA.transpose(1, 0, 2)
    dE_rows = dE.transpose(1, 0, 2).reshape(n * P, n)  # row (r, i): row r of ∂E/∂θ_i
    AB_V = np.column_stack([A_V, B_V])
    return E0, A0, E_V, A_V, B_V, dE.reshape(P, -1), dA.reshape(P, -1), dAB_rows, dE_rows, AB_V


def continuous_derivatives(theta, speed: float, known: KnownParameters):
    """Ac (6, 6), Bc (6,), their θ-derivatives (8, 6, 6), (8, 6) and V-derivatives (6, 6), (6,), for one
    parameter set and speed (the same as :func:`~online_id.model.lateral.continuous_parameter_derivatives`
    and :func:`continuous_speed_derivatives`, in a few products: E, A, B are affine in θ and V).

    From E Ac = A: ∂Ac/∂q = E⁻¹ (∂A/∂q − ∂E/∂q Ac), ∂Bc/∂q = E⁻¹ (∂B/∂q − ∂E/∂q Bc) for q = θ_i, V
    (∂B/∂θ = 0). Returns ``(Ac, Bc, dAc, dBc, dAc_dV, dBc_dV)``.
    """
    AB, d = derivative_blocks(theta, speed, known)
    n = N_STATES
    return AB[:, :n], AB[:, n], d[:-1, :, :n], d[:-1, :, n], d[-1, :, :n], d[-1, :, n]


def derivative_blocks(theta, speed: float, known: KnownParameters):
    """:func:`continuous_derivatives` as blocks: [Ac, Bc] (6, 7) and [∂Ac/∂q, ∂Bc/∂q] (9, 6, 7) for q = θ_1..θ_8,
    then V (the top rows of G = [[Ac, Bc], [0, 0]] and of its derivatives), in one compiled call
    (:func:`online_id.model.compiled.descriptor_blocks`, LAPACK's gesv for both systems); raises
    ``numpy.linalg.LinAlgError`` where E is singular."""
    E0, A0, E_V, A_V, B_V, dE_flat, dA_flat, dAB_rows, dE_rows, AB_V = _affine_coefficients(known)
    try:
        return compiled.descriptor_blocks(E0, A0, E_V, A_V, B_V, dE_flat, dA_flat, dAB_rows, dE_rows, AB_V,
                                          np.ascontiguousarray(theta, dtype=float), float(speed))
    except np.linalg.LinAlgError as exc:
        raise np.linalg.LinAlgError(f"singular matrix E of the descriptor model ({exc})") from None


@dataclass(frozen=True)
class SpectralForm:
    """G = [[Ac, Bc], [0, 0]] (7 × 7) as Q diag(λ) Q⁻¹, and K directions dG_k in its eigenbasis.

    With it, the zero-order-hold transition Φ(dt) = expm(G dt) = [[Ad, Bd], [0, 1]] for any sample
    period is Q diag(e^(λ dt)) Q⁻¹, and the Fréchet derivative of expm in direction dG_k is
    (Daleckii-Krein)

        L_k(dt) = Q (D(dt) ∘ W_k) Q⁻¹,   W_k = Q⁻¹ dG_k Q,
        D_ab(dt) = (e^(λa dt) − e^(λb dt)) / (λa − λb)  (= dt e^(λa dt) when λa = λb),

    both exact for a diagonalisable G up to round-off of about ``condition`` · 1e-16.

    Shapes (leading axes ``...`` batch several matrices): ``eigenvalues`` (..., 7), ``vectors`` and
    ``inverse`` (..., 7, 7), ``directions`` (..., K, 7, 7) (the W_k), complex.
    """

    eigenvalues: np.ndarray
    vectors: np.ndarray
    inverse: np.ndarray
    directions: np.ndarray
    condition: np.ndarray

    @cached_property
    def _gaps(self):
        """Of one decomposition: (1/(λa − λb) (7, 7) off the diagonal, 0 on it; the smallest |λa − λb| off
        the diagonal). Cached on the instance (``cached_property`` writes the instance ``__dict__``, which
        a frozen dataclass without ``slots`` has)."""
        lam = self.eigenvalues
        diagonal = np.diag_indices(len(lam))
        gap = lam[:, None] - lam[None, :]
        distance = np.abs(gap)
        distance[diagonal] = np.inf
        smallest = float(distance.min())
        if not smallest > 0:  # two equal eigenvalues: the divided differences take the series (weights)
            return np.zeros_like(gap), smallest
        gap[diagonal] = 1.0
        inverse = 1.0 / gap
        inverse[diagonal] = 0.0
        return inverse, smallest

    @property
    def usable(self) -> bool:
        """Every decomposition's round-off stays under ~1e-10 (see :data:`SPECTRAL_CONDITION_LIMIT`)."""
        condition = self.condition
        if condition.ndim == 0:  # (one decomposition: the filters' every new point asks)
            return float(condition) < SPECTRAL_CONDITION_LIMIT
        return bool(np.all(condition < SPECTRAL_CONDITION_LIMIT))

    def weights(self, dt):
        """e^(λ dt) (..., m, 7) and the divided differences D(dt) (..., m, 7, 7) for periods ``dt`` (m,).

        D_ab = dt (e^(μa) − e^(μb)) / (μa − μb) with μ = λ dt; where |μa − μb| < 1e-3 (the difference
        would cancel) D_ab = dt e^(μb) φ1(μa − μb) with φ1(z) = (e^z − 1)/z by its Taylor series to z⁴
        (truncation under 1e-18, cancellation in the difference form under 1e-13).
        """
        dt = np.asarray(dt, dtype=float)
        mu = self.eigenvalues[..., None, :] * dt[:, None]
        e = np.exp(mu)
        if self.eigenvalues.ndim == 1 and len(dt) and self._gaps[1] * dt.min() >= DIVIDED_DIFFERENCE_CLOSE:
            # one decomposition, no two eigenvalues close at any of these periods (the usual case):
            # D_ab = (e^(μa) − e^(μb)) / (λa − λb) from the decomposition's own 1/(λa − λb)
            inverse_gap, _ = self._gaps
            D = (e[:, :, None] - e[:, None, :]) * inverse_gap
            idx = np.arange(e.shape[-1])
            D[:, idx, idx] = dt[:, None] * e
            return e, D
        z = mu[..., :, None] - mu[..., None, :]
        close = np.abs(z) < DIVIDED_DIFFERENCE_CLOSE
        if np.count_nonzero(close) > e.size:  # besides the diagonal, some eigenvalues are close: series there
            c = PHI1_SERIES
            series = e[..., None, :] * (1 + z * (c[0] + z * (c[1] + z * (c[2] + z * c[3]))))
            diff = (e[..., :, None] - e[..., None, :]) / np.where(close, 1.0, z)
            D = np.where(close, series, diff)
        else:  # only the diagonal is close (the usual case)
            D = (e[..., :, None] - e[..., None, :]) / np.where(close, 1.0, z)
            idx = np.arange(e.shape[-1])
            D[..., idx, idx] = e
        return e, dt[:, None, None] * D

    def period_table(self, dt: float):
        """Of one decomposition, for one period ``dt`` [s]: Φ(dt) (7, 7) and every direction's L_k(dt)
        (K, 7, 7), real (the terms of :meth:`transitions`, once for every sample of that period); one
        decomposition's in one compiled call (:func:`online_id.model.compiled.period_table`)."""
        if self.eigenvalues.ndim == 1:
            n, K = len(self.vectors), len(self.directions)
            Phi, L = np.empty((n, n)), np.empty((K, n, n))
            c = np.ascontiguousarray
            compiled.period_table(c(self.eigenvalues), c(self.vectors), c(self.inverse), c(self.directions),
                                  float(dt), DIVIDED_DIFFERENCE_CLOSE, PHI1_SERIES, Phi, L)
            return Phi, L
        e, D = self.weights(np.array([dt]))
        Q, Qi = self.vectors, self.inverse
        K, n = len(self.directions), len(Q)
        Phi = ((Q * e[0]) @ Qi).real
        QDW = Q @ (D[0] * self.directions).transpose(1, 0, 2).reshape(n, K * n)  # Q (D ∘ W_k) side by side
        L = (QDW.reshape(n, K, n).transpose(1, 0, 2).reshape(K * n, n) @ Qi).real.reshape(K, n, n)
        return Phi, L

    def local_tables(self, dt: float, n_params: int, order: int = 0):
        """Of one decomposition, for one period ``dt`` [s]: :meth:`period_table`'s Φ and L_k flat, the first
        ``n_params`` directions' columns table, and :meth:`input_table`'s columns of an input polynomial of
        ``order`` derivatives flat (empty for 0), in one compiled call
        (:func:`online_id.model.compiled.local_tables`: a filter's new linearisation point)."""
        return compiled.local_tables(self.eigenvalues, self.vectors, self.inverse, self.directions, float(dt),
                                     DIVIDED_DIFFERENCE_CLOSE, PHI1_SERIES, int(n_params), int(order))

    def input_table(self, dt: float, order: int = 3):
        """Of one decomposition, for one period ``dt`` [s]: the input columns Γ_j = [φ_j(G dt)]_{0:6, 6},
        j = 1..``order`` (6, order), and their first-order terms in each direction (K, 6, order), real: the
        columns of an input polynomial's derivatives (:mod:`online_id.model.intersample`; Γ_0 = Bd is
        :meth:`period_table`'s). In the eigenbasis, with q = Q⁻¹[:, 6] and μ = λ dt,

            Γ_j = Re(Q (φ_j(μ) ∘ q))[:6],   L_k Γ_j = Re(Q ((dt φ_j[μ_a, μ_b] ∘ W_k) q))[:6],

        φ_j of each eigenvalue on its own and their divided differences (:func:`online_id.model.compiled.phi_weights`;
        the products in :func:`online_id.model.compiled.input_table`). Round-off: that of Φ, about the
        eigenvectors' condition number times 1e-13 of each column (tests/test_filters_discretisation.py)."""
        Gamma = np.empty((N_STATES, order))
        LG = np.empty((len(self.directions), N_STATES, order))
        c = np.ascontiguousarray
        compiled.input_table(c(self.eigenvalues), c(self.vectors), c(self.inverse), c(self.directions), float(dt),
                             DIVIDED_DIFFERENCE_CLOSE, PHI1_SERIES, Gamma, LG)
        return Gamma, LG

    def phi_weights(self, dt: float, order: int = 3):
        """φ_0 … φ_order of each μ = λ ``dt`` (order + 1, 7) and the divided differences of φ_1 … φ_order
        (order, 7, 7), complex (:func:`online_id.model.compiled.phi_weights`)."""
        n = len(self.eigenvalues)
        phi = np.empty((order + 1, n), dtype=complex)
        dd = np.empty((order, n, n), dtype=complex)
        compiled.phi_weights(np.ascontiguousarray(self.eigenvalues * dt), DIVIDED_DIFFERENCE_CLOSE, PHI1_SERIES,
                             phi, dd)
        return phi, dd

    def transitions(self, dt, coefficients=None):
        """Φ at G + Σ_k c_k dG_k, first order in c: (..., m, 7, 7), real.

        ``dt`` (m,) sample periods [s]; ``coefficients`` (m, K) or None (Φ at G itself, exact).
        Error: the neglected second-order term of expm, about ½ ‖Σ c_k dG_k dt‖².
        """
        return self.transitions_weighted(self.weights(dt), coefficients)

    def transitions_weighted(self, weights, coefficients=None):
        """:meth:`transitions` with the :meth:`weights` of the periods already computed."""
        e, D = weights
        if self.eigenvalues.ndim == 1 and coefficients is not None:  # one decomposition: 2-D products
            m, n = e.shape
            W = self.directions.reshape(len(self.directions), -1)
            M = D * (np.asarray(coefficients, dtype=float) @ W).reshape(m, n, n)
            idx = np.arange(n)
            M[:, idx, idx] += e
            QM = self.vectors @ M.transpose(1, 0, 2).reshape(n, m * n)  # Q M_j side by side (2-D: BLAS)
            QM = QM.reshape(n, m, n).transpose(1, 0, 2).reshape(m * n, n)
            return (QM @ self.inverse).real.reshape(m, n, n)
        if coefficients is None:
            M = np.zeros(D.shape, dtype=complex)
        else:
            W = self.directions
            c = np.asarray(coefficients, dtype=float)
            M = D * (c @ W.reshape(W.shape[:-2] + (-1,))).reshape(W.shape[:-3] + (len(c),) + W.shape[-2:])
        idx = np.arange(e.shape[-1])
        M[..., idx, idx] += e
        return _real_of_product(_cmatmul(self.vectors[..., None, :, :], M), self.inverse[..., None, :, :])

    def directional(self, dt, z, directions: slice = slice(None)):
        """L_k(dt_j) z_j for each sample j and direction k: (..., m, K, 7), real.

        ``dt`` (m,), ``z`` (m, 7) (the augmented [x; δ] each transition applies to).
        """
        return self.directional_weighted(self.weights(dt), z, directions)

    def directional_weighted(self, weights, z, directions: slice = slice(None)):
        """:meth:`directional` with the :meth:`weights` of the periods already computed; weights of one
        period (m = 1) apply to every z."""
        D = weights[1]
        W = self.directions[..., directions, :, :]
        y = z @ np.swapaxes(self.inverse, -1, -2)  # z in the eigenbasis, (..., m, 7)
        if D.shape[-3] == 1:  # one period: (D ∘ W_k) y_j for every j in one product
            DW = D[..., 0, None, :, :] * W  # (..., K, 7, 7)
            K = _cmatmul(y, np.swapaxes(DW.reshape(DW.shape[:-3] + (-1, DW.shape[-1])), -1, -2))
            K = K.reshape(K.shape[:-1] + DW.shape[-3:-1])
        elif self.eigenvalues.ndim == 1:  # K[j, k, a] = Σ_b (D_j[a, b] y_j[b]) W_k[a, b]: a batch over a
            U = (D * y[:, None, :]).transpose(1, 0, 2)  # (7, m, 7)
            K = (U @ W.transpose(1, 2, 0)).transpose(1, 2, 0)  # (7, m, K) → (m, K, 7)
            m, k, n = K.shape
            return (K.reshape(m * k, n) @ self.vectors.T).real.reshape(m, k, n)
        else:
            K = ((D * y[..., :, None, :])[..., :, None, :, :] * W[..., None, :, :, :]).sum(axis=-1)
        return _real_of_product(K, np.swapaxes(self.vectors, -1, -2)[..., None, :, :])


def spectral_form(Ac, Bc, dAc, dBc) -> SpectralForm:
    """The :class:`SpectralForm` of G = [[Ac, Bc], [0, 0]] with directions [[dAc_k, dBc_k], [0, 0]].

    Ac (..., 6, 6), Bc (..., 6), dAc (..., K, 6, 6), dBc (..., K, 6).
    """
    G = _augmented(np.asarray(Ac, dtype=float), np.asarray(Bc, dtype=float), 1.0)
    dG = _augmented(np.asarray(dAc, dtype=float), np.asarray(dBc, dtype=float), 1.0)
    if G.ndim == 2:
        return single_spectral_form(G, dG)
    lam, Q = np.linalg.eig(G)
    Q = Q.astype(complex)
    Qi = np.linalg.inv(Q)
    condition = np.abs(Q).sum(axis=-2).max(axis=-1) * np.abs(Qi).sum(axis=-2).max(axis=-1)
    W = (Qi[..., None, :, :] @ dG) @ Q[..., None, :, :]  # a batch of K: numpy's complex matmul is the cheaper here
    return SpectralForm(lam.astype(complex), Q, Qi, W, condition)


def single_spectral_form(G, dG) -> SpectralForm:
    """:func:`spectral_form` of one G (7, 7) and its K directions dG (K, 7, 7), given whole: LAPACK's dgeev
    called directly (numpy's ``eig`` wraps the same routine at twice the cost for a 7 × 7), the rest in one
    compiled call (:func:`online_id.model.compiled.eigenbasis`)."""
    if not math.isfinite(G.sum()):  # (LAPACK would print to stderr, or return NaN vectors without an error; a NaN
        # or an inf makes the sum NaN or inf)
        raise np.linalg.LinAlgError("Array must not contain infs or NaNs")
    wr, wi, _, vr, info = lapack.dgeev(G, compute_vl=0)
    if info > 0:  # the QR algorithm did not converge: numpy's eig raises LinAlgError, as before
        lam, Q = np.linalg.eig(G)
        lam, Q = lam.astype(complex), Q.astype(complex)
        Qi = np.linalg.inv(Q)
        condition = np.abs(Q).sum(axis=-2).max() * np.abs(Qi).sum(axis=-2).max()
        W = Qi @ dG @ Q
    else:  # pairs, Q⁻¹, W_k and the condition in one compiled call
        try:
            lam, Q, Qi, W, condition = compiled.eigenbasis(wr, wi, vr, np.asarray(dG, dtype=float))
        except np.linalg.LinAlgError as exc:
            raise np.linalg.LinAlgError(f"singular eigenvector matrix ({exc})") from None
    return SpectralForm(lam, Q, Qi, W, np.asarray(condition))
