"""Extra states of the online filters: sensor offsets and effect parameters estimated with the 8.

The augmented state grows from [x (6), s (8)] to [x, s, e (n)]. Each e_i is additive, in SI units
(not log-scale: an offset may be zero or negative), follows a random walk, and enters the model
linearly (see :class:`online_id.effects.base.ExtraState`, which an effect's
:meth:`~online_id.effects.base.Effect.filter_states` returns):

    δ = δH / i_s + g·e                                 (g: ``steering``, (n,))
    y_logged = C x + D δ + M e + Σ_i e_i K_i x          (M: ``output``, (5, n); K: ``output_state``, (n, 5, 6))

so that, for the filters, ∂δ/∂e = g, and ∂y/∂e = D gᵀ + M + [K_i x]_i besides the path through x.
A tyre's friction coefficient μ (``ExtraState.tyre_axles``) is an exception: it acts through the
saturating force law, and :attr:`Augmentation.has_tyres` makes the filters use that model
(:mod:`online_id.filters.tyre_filters`). A time lag (``ExtraState.lags``) is the other: the filters read the
lagged channels e later (:mod:`online_id.filters.lagged`), and their sensitivity to it is

    ∂y/∂e = −L ∘ ẏ,   ẏ = C (A x + B δ)                 (L: ``lag``, (5, n), 1 where e lags the channel)

with no term in the mean (the reading at t + ê is the model's output at t).
:class:`Augmentation` holds these arrays; the EKF and UKF consume it without knowing the effects.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from online_id.effects.base import Effect, ExtraState
from online_id.errors import OnlineIdError
from online_id.model.lateral import N_PARAMS, N_STATES, OUTPUT_NAMES
from online_id.vehicle.parameters import KnownParameters

#: The length of the augmented state before the extra states: the model states, then the 8 log-scale parameters.
N_AUG = N_STATES + N_PARAMS
#: The log-scale parameters in the augmented state; extra states (offsets, effects) follow them.
PARAMS = slice(N_STATES, N_AUG)
N_OUT = len(OUTPUT_NAMES)
#: The name a lag uses for the speed channel (ExtraState.lags).
SPEED = "speed"


class Augmentation:
    """The extra states, as arrays the filters use (see the module docstring).

    Attributes
    ----------
    states : the :class:`ExtraState` descriptions, in state order
    n : number of extra states
    initial, prior_std, random_walk_variance : (n,) [unit, unit, unit²/s]
    output : (5, n) M;  output_state : (n, 5, 6) K;  steering : (n,) g
    """

    def __init__(self, states: Sequence[ExtraState] = ()):
        self.states = tuple(states)
        self.n = len(self.states)
        keys = [(s.group, s.key, s.parameter) for s in self.states]
        if len(set(keys)) != len(keys):
            raise OnlineIdError("the same offset or effect is asked for twice")
        self.initial = np.array([s.initial for s in self.states], dtype=float)
        self.prior_std = np.array([s.prior_std for s in self.states], dtype=float)
        self.random_walk_variance = np.array([s.random_walk for s in self.states], dtype=float) ** 2
        self.output = np.array([s.output for s in self.states], dtype=float).reshape(self.n, N_OUT).T
        self.output_state = np.zeros((self.n, N_OUT, N_STATES))
        for i, s in enumerate(self.states):
            if s.output_state is not None:
                self.output_state[i] = np.asarray(s.output_state, dtype=float)
        self.steering = np.array([s.steering for s in self.states], dtype=float)
        self.couples_state = bool(np.any(self.output_state))
        #: the friction coefficient's state index (among the extra states) of each axle, or -1: the
        #: saturating tyre law (online_id.model.tyres) is on when any axle has one
        self.tyre_mu = np.full(2, -1, dtype=np.int64)
        for i, s in enumerate(self.states):
            for axle in s.tyre_axles:
                if self.tyre_mu[axle] >= 0:
                    raise OnlineIdError("a tyre friction coefficient is asked for twice on one axle")
                self.tyre_mu[axle] = i
        self.has_tyres = bool((self.tyre_mu >= 0).any())
        #: the tyre law's axle loads (known, a_x) → (n, 2 or 4) when they follow each sample's longitudinal
        #: acceleration (``load_transfer``, ``combined_slip``), else None
        self.axle_loads = next((s.axle_loads for s in self.states if s.axle_loads is not None), None)
        self.moves_loads = self.axle_loads is not None
        #: lags: which measured channels (rows) each state delays, and whether it delays the speed
        self.lag = np.array([[c in s.lags for s in self.states] for c in OUTPUT_NAMES], dtype=float).reshape(N_OUT,
                                                                                                             self.n)
        self.lag_speed = np.array([SPEED in s.lags for s in self.states], dtype=float)
        self.has_lags = bool(self.lag.any() or self.lag_speed.any())
        unknown = {c for s in self.states for c in s.lags} - set(OUTPUT_NAMES) - {SPEED}
        if unknown:
            raise OnlineIdError(f"a lag on unknown channel(s) {', '.join(sorted(unknown))}")

    @classmethod
    def from_effects(cls, effects: Sequence[Effect], known: KnownParameters) -> Augmentation:
        """The extra states of ``effects`` (each effect's :meth:`filter_states`; raises for an effect
        without a filter form)."""
        return cls([s for e in effects for s in e.filter_states(known)])

    def __bool__(self) -> bool:
        return self.n > 0

    # -- the model terms, at extra-state values e ---------------------------------------------------
    def steering_shift(self, e) -> float | np.ndarray:
        """g·e: added to the road-wheel angle [rad]; e (n,) → scalar, or (S, n) → (S,)."""
        return e @ self.steering

    def output_offset(self, e) -> np.ndarray:
        """M e: added to the outputs; e (n,) → (5,), or (S, n) → (S, 5)."""
        return e @ self.output.T

    def output_matrix(self, e) -> np.ndarray:
        """Σ_i e_i K_i, added to the output matrix C; e (n,) → (5, 6), or (S, n) → (S, 5, 6)."""
        return np.tensordot(e, self.output_state, axes=(-1, 0))

    def sensitivity(self, D, x_sum, count, rate_sum=None) -> np.ndarray:
        """Direct sensitivity ∂y/∂e (5, n) summed over ``count`` samples whose states sum to ``x_sum``
        (6,), with the road-wheel angle's output row ``D`` (5,), and, with lags, the outputs' rates ẏ summed
        (``rate_sum``, (5,)); the path through x is the filter's."""
        H = count * (np.outer(D, self.steering) + self.output)
        if self.couples_state:
            H += np.einsum("nij,j->in", self.output_state, x_sum)
        if rate_sum is not None:
            H -= self.lag * rate_sum[:, None]
        return H

    def lag_offset(self, e, e_read) -> np.ndarray:
        """Σ_i L_i (e_i − ê_i) per output (..., 5): how much later than it was read each channel really lags
        (e (..., n), the lags the channels were read at ``e_read`` (n,)); times −ẏ, the outputs' correction."""
        return (np.asarray(e) - e_read) @ self.lag.T

    def channel_lags(self, e) -> tuple[np.ndarray, float]:
        """The lag of each measured channel (5,) and of the speed [s] at extra states e (n,)."""
        return self.lag @ e, float(self.lag_speed @ e)

    def axle_mu(self, e) -> np.ndarray:
        """μ of each axle (..., 2) from extra states e (..., n); an axle without a μ state is linear (μ = ∞)."""
        e = np.asarray(e, dtype=float)
        out = np.full(e.shape[:-1] + (2,), np.inf)
        for axle in range(2):
            if self.tyre_mu[axle] >= 0:
                out[..., axle] = e[..., self.tyre_mu[axle]]
        return out

    # -- reading ------------------------------------------------------------------------------------
    def report(self, values, std) -> dict:
        """``{"offsets": {channel: {value, std, unit}}, "effects": {label: {parameter: {...}}}}`` (groups
        without states left out)."""
        out: dict = {}
        for s, v, sd in zip(self.states, values, std):
            entry = {"value": float(v), "std": float(sd), "unit": s.unit}
            if s.group == "offsets":
                out.setdefault("offsets", {})[s.key] = entry
            else:
                out.setdefault(s.group, {}).setdefault(s.key, {})[s.parameter] = entry
        return out
