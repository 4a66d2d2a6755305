"""online-id: online identification of a car's lateral-dynamics parameters.

Core packages (they import neither ``drivers`` nor ``replay``):

* ``online_id.vehicle``: parameter sets with names and units, vehicle TOML files
* ``online_id.model``: the yaw-roll-sideslip-relaxation model, its discretisation and Jacobians
* ``online_id.sim``: test manoeuvres and the simulator
* ``online_id.io``: the track-run CSV log
* ``online_id.stream``: the sample stream and its gaps; ``online_id.filters``: the online EKF and UKF
* ``online_id.batchfit``: the batch fit (cost, GA, polish); ``online_id.diagnosis``: the sim-to-real gap
* ``online_id.trust``: check, plausibility, identifiability, consistency; ``online_id.util``: small helpers
* ``online_id.cli``: the ``online-id`` command
* ``online_id.workflows``: one function per job (estimate, fit, diagnose, check, listen, convergence): the
  only path from a front end into the core
* ``online_id.api``: those workflows for notebooks (reachable as ``online_id.estimate``, ...; loaded on first
  use, so ``import online_id`` stays cheap)
"""

__version__ = "0.1.0"

#: Names loaded from online_id.api on first use (PEP 562): its ``__all__`` (tests/test_api.py holds them equal).
_API = ("estimate", "fit", "diagnose", "check", "Estimate", "Fit", "Diagnosis", "Check", "Value")


def __getattr__(name: str):
    if name in _API:
        from online_id import api

        return getattr(api, name)
    raise AttributeError(f"module 'online_id' has no attribute {name!r}")


def __dir__():
    return sorted([*globals(), *_API])
