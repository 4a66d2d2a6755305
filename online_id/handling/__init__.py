"""Handling metrics of the identified car with σ (:mod:`online_id.handling.metrics`) and the run's own
yaw-rate/steering response to compare with (:mod:`online_id.handling.measured`)."""

from online_id.handling.metrics import Handling, Metric, handling

__all__ = ["Handling", "Metric", "handling"]
