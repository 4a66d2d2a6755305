"""The oracle of the batch paths with a steering that is not held over a sample (issue 36): a plain per-sample
recursion of the exact step, each step from :func:`online_id.model.intersample.reference_step` (scipy's expm of
the augmented generator) at the step's own speed, the inputs from :func:`online_id.model.intersample.run_inputs`.

    x[k+1] = Ad(S_k) x[k] + Γ(S_k) w_k,   y[k] = C(V_k) x[k] + D(V_k) δ_k,

w_k the input polynomial of the step from sample k to k + 1 and S_k its speed (the mean of the two samples'; the
hold: δ_k and V_k). Slow (one 10×10 matrix exponential per distinct step speed), written for reading.
"""

from __future__ import annotations

import numpy as np

from online_id.model import intersample as its
from online_id.model.lateral import continuous_matrices, outputs_from_continuous


def reference_run(theta, known, steering_wheel_angle, speed, dt: float, kind: str, x0=None):
    """States (n, 6) and outputs (n, 5) [r, φ, p, a_y, v_y] of the model driven by the steering-wheel angle (n,) [rad]
    at ``speed`` (n,) [m/s], sampled every ``dt`` [s], the steering between samples of ``kind``."""
    theta = np.asarray(theta.to_vector() if hasattr(theta, "to_vector") else theta, dtype=float)
    delta = np.asarray(steering_wheel_angle, dtype=float) / known.steering_ratio
    n = len(delta)
    V = np.broadcast_to(np.asarray(speed, dtype=float), (n,))
    W, S = its.run_inputs(kind, np.arange(n) * dt, delta, V)
    steps: dict[float, tuple] = {}

    def step(v):
        if v not in steps:
            steps[v] = its.reference_step(*continuous_matrices(theta, v, known), dt)
        return steps[v]

    x = np.zeros(6) if x0 is None else np.asarray(x0, dtype=float).copy()
    states, out = np.empty((n, 6)), np.empty((n, 5))
    for k in range(n):
        C, D = outputs_from_continuous(*continuous_matrices(theta, V[k], known), np.asarray(V[k]))
        states[k], out[k] = x, C @ x + D * delta[k]
        if k + 1 < n:
            Ad, Gamma = step(float(S[k + 1]))
            x = Ad @ x + Gamma @ W[k + 1]
    return states, out
