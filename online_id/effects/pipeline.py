"""The base model with effects: logged steering in, logged channels out."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from online_id.effects.base import Effect
from online_id.errors import OnlineIdError
from online_id.vehicle.parameters import KnownParameters


def predict(theta, effects: Sequence[Effect], known: KnownParameters, logged_steering, speed, dt: float,
            method: str = "picard", **options) -> tuple[np.ndarray, np.ndarray]:
    """States (N, 6) and logged outputs (N, 4) [r, φ, p, a_y] of the model with ``effects``.

    The stages run in order: input effects turn the logged steering into what the car sees, dynamics
    effects change the model, sensor effects turn true outputs into logged ones. ``method`` is how a
    force law is solved (:func:`online_id.sim.forces.simulate_with_forces`, which also takes
    ``options`` such as ``tol`` and ``warm``).
    """
    from online_id.sim.forces import simulate_with_forces  # scipy: imported on first use, not by the CLI

    steering = np.asarray(logged_steering, dtype=float)
    theta = np.asarray(theta, dtype=float)
    for e in effects:
        steering = e.car_steering(steering)
        theta = e.transform_theta(theta, known)
    laws = [law for e in effects if (law := e.force_law(theta, known)) is not None]
    if len(laws) > 1:
        raise OnlineIdError("only one force-law effect at a time")
    states, outputs = simulate_with_forces(theta, known, steering, speed, dt, laws[0] if laws else None,
                                           method=method, **options)
    for e in effects:
        outputs = e.measure(outputs, dt)
    return states, outputs
