"""Online estimators: the model states plus the 8 parameters, updated sample by sample.

``base`` holds what every variant shares (the augmented state, the hooks, the reading of the estimate), with
``feeding`` (samples into the hooks) and ``health`` (gating, resets, convergence); a new filter is a module here
that subclasses :class:`OnlineEstimator`, implements its abstract hooks and has one entry in :data:`FILTERS`
(``registry``). Importing this package imports no filter (nor filterpy): the classes below are imported when
first asked for, as the registry's are.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

from online_id.filters.registry import FILTERS, FilterEntry, filter_class, tyre_filters

if TYPE_CHECKING:  # (for readers and the docs; at run time they come from __getattr__)
    from online_id.filters.base import OnlineEstimator
    from online_id.filters.config import FilterConfig
    from online_id.filters.ekf import EKFEstimator
    from online_id.filters.ukf import UKFEstimator

#: What this package hands on, imported when first asked for: name -> module.
_LAZY = {"OnlineEstimator": "online_id.filters.base", "FilterConfig": "online_id.filters.config",
         "EKFEstimator": "online_id.filters.ekf", "UKFEstimator": "online_id.filters.ukf"}


def __getattr__(name: str):
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    if name == "TYRE_FILTERS":  # the saturating-tyre filters by name, derived from FILTERS
        return tyre_filters()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["FILTERS", "TYRE_FILTERS", "EKFEstimator", "FilterConfig", "FilterEntry", "OnlineEstimator",
           "UKFEstimator", "filter_class", "tyre_filters"]
