"""Test manoeuvres (``maneuvers``) and the simulator that turns them into track runs (``simulator``)."""
