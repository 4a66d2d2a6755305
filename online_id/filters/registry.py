"""The online filters by name: one registry, imported on use (python-can's ``BACKENDS``).

Each name (what ``--filter`` takes) maps to a :class:`FilterEntry`: where its class for the linear tyres and its
class for the saturating tyres are, as ``"module:Class"`` strings. Nothing is imported until a class is asked
for (:func:`filter_class`), so the CLI reads its choices from :data:`FILTERS` without loading filterpy, and a
filter's optional dependencies stay optional. A new filter is one entry here; ``make_estimator``, the CLI's
``--filter`` choices and ``tests/test_filters_contract.py`` take it from the registry.
"""

from __future__ import annotations

import importlib
import warnings
from dataclasses import dataclass

from online_id.errors import OnlineIdError


@dataclass(frozen=True)
class FilterEntry:
    """Where one filter's classes are, as ``"module:Class"``.

    ``linear``: the filter of the linear-tyre model (the 8 parameters, sensor offsets, effects' extra states,
    a delay's lagged outputs); ``tyres``: the same filter of the saturating-tyre model (a friction coefficient μ,
    one or one per axle, among the extra states), None when the filter has no such form.
    """

    linear: str
    tyres: str | None = None

    def path(self, tyres: bool = False) -> str | None:
        """The ``"module:Class"`` of the form asked for (None: this filter has no saturating-tyre form)."""
        return self.tyres if tyres else self.linear

    def __call__(self, *args, **kwargs):
        """Deprecated: the linear-tyre filter built with these arguments, as ``FILTERS[name](vehicle, ...)`` did
        when the registry held classes (kept for one release; use :func:`filter_class`)."""
        warnings.warn("FILTERS[name](...) is deprecated: FILTERS holds FilterEntry records now; use"
                      " online_id.filters.registry.filter_class(name)(...)", DeprecationWarning, stacklevel=2)
        module, _, cls = self.linear.partition(":")
        return getattr(importlib.import_module(module), cls)(*args, **kwargs)


#: The filters by the name ``--filter`` takes; the first is the default.
FILTERS: dict[str, FilterEntry] = {
    "ekf": FilterEntry("online_id.filters.ekf:EKFEstimator", "online_id.filters.tyre_filters:TyreEKFEstimator"),
    "ukf": FilterEntry("online_id.filters.ukf:UKFEstimator", "online_id.filters.tyre_filters:TyreUKFEstimator"),
}


def filter_class(name: str, tyres: bool = False) -> type:
    """The :class:`~online_id.filters.base.OnlineEstimator` subclass registered as ``name``: its linear-tyre form,
    or with ``tyres`` its saturating-tyre form. An unknown name, or a filter without that form, is an
    :class:`~online_id.errors.OnlineIdError` that names the choices."""
    entry = FILTERS.get(name)
    if entry is None:
        raise OnlineIdError(f"unknown filter {name!r}; choose from {', '.join(FILTERS)}")
    path = entry.path(tyres)
    if path is None:
        with_tyres = [n for n, e in FILTERS.items() if e.tyres]
        raise OnlineIdError(f"filter {name!r} has no saturating-tyre form (needed by a tyre effect such as"
                            f" tire_saturation); filters that have one: {', '.join(with_tyres) or 'none'}")
    module, _, cls = path.partition(":")
    return getattr(importlib.import_module(module), cls)


def tyre_filters() -> dict[str, type]:
    """The saturating-tyre form of every filter that has one, by name (derived from :data:`FILTERS`)."""
    return {name: filter_class(name, tyres=True) for name, entry in FILTERS.items() if entry.tyres}
