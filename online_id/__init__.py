"""online-id: online identification of a car's lateral-dynamics parameters.

Core packages (they import neither ``drivers`` nor ``replay``):

* ``online_id.vehicle``: parameter sets with names and units, vehicle TOML files
* ``online_id.model``: the yaw-roll-sideslip-relaxation model, its discretisation and Jacobians
* ``online_id.sim``: test manoeuvres and the simulator
* ``online_id.io``: the track-run CSV log
* ``online_id.cli``: the ``online-id`` command
"""

__version__ = "0.1.0"
