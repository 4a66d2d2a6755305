"""Online estimators: the model states plus the 8 parameters, updated sample by sample.

``base`` holds what every variant shares (guards, gating, reading the estimate); a new filter is a
module here that subclasses :class:`OnlineEstimator` and implements its hooks.
"""

from online_id.filters.base import OnlineEstimator
from online_id.filters.config import FilterConfig
from online_id.filters.ekf import EKFEstimator
from online_id.filters.ukf import UKFEstimator

#: Filters by the name the CLI's --filter takes.
FILTERS = {"ekf": EKFEstimator, "ukf": UKFEstimator}

__all__ = ["FILTERS", "EKFEstimator", "FilterConfig", "OnlineEstimator", "UKFEstimator"]
