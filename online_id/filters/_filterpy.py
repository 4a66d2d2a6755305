"""filterpy, the one way in: its EKF and UKF classes without the rest of filterpy at import.

filterpy's ``__init__`` imports every subpackage (``discrete_bayes`` imports ``scipy.ndimage``,
``monte_carlo``, ``stats`` imports ``scipy.stats``, ...), and ``filterpy.kalman``'s modules import
``filterpy.stats`` for one function, ``logpdf``, called only when a filter's ``likelihood`` is read (online-id
never reads it): together 0.5-1.1 s of every command's start-up for nothing (issue 26).

Before filterpy is first imported, this module puts two light stand-ins in ``sys.modules``: ``filterpy``,
whose subpackages load when first named (``filterpy.kalman`` at once, below), and ``filterpy.stats``,
whose ``logpdf`` loads the real function on its first call and whose other names load filterpy's own
``filterpy/stats/stats.py`` and hand its attribute on. filterpy's code runs unchanged; code that uses
any part of filterpy gets filterpy's own objects. Where filterpy is already imported it is used as it is.
"""

from __future__ import annotations

import importlib
import importlib.util
import sys
import types
from pathlib import Path


class _LazyPackage(types.ModuleType):
    """A package whose names load its submodule (``filterpy.kalman``), or the module ``real``, when first used."""

    real: str | None = None

    def __getattr__(self, name: str):
        if name == "__version__" and self.__name__ == "filterpy":  # read from its metadata when first asked
            self.__version__ = _version()  # (not at import: importlib.metadata's search costs start-up)
            return self.__version__
        if name.startswith("__"):
            raise AttributeError(name)
        if self.real is not None:
            return getattr(importlib.import_module(self.real), name)
        try:
            return importlib.import_module(f"{self.__name__}.{name}")
        except ModuleNotFoundError:
            raise AttributeError(f"module {self.__name__!r} has no attribute {name!r}") from None


def _package(name: str, folder: Path) -> _LazyPackage:
    module = _LazyPackage(name, __doc__)
    module.__spec__ = importlib.util.spec_from_file_location(name, folder / "__init__.py",
                                                             submodule_search_locations=[str(folder)])
    module.__path__, module.__file__, module.__package__ = [str(folder)], str(folder / "__init__.py"), name
    return module


def _logpdf(*args, **kwargs):
    return importlib.import_module("filterpy.stats.stats").logpdf(*args, **kwargs)


def _install_stand_ins() -> None:
    if "filterpy" in sys.modules:
        return  # imported already: as it is
    top = importlib.util.find_spec("filterpy")  # finds the package without importing it
    if top is None or not top.submodule_search_locations:
        return  # not the filterpy we know: import it the usual way
    folder = Path(top.submodule_search_locations[0])
    if not ((folder / "kalman" / "__init__.py").is_file() and (folder / "stats" / "stats.py").is_file()):
        return
    filterpy = _package("filterpy", folder)
    stats = _package("filterpy.stats", folder / "stats")
    stats.real = "filterpy.stats.stats"
    stats.logpdf = _logpdf
    sys.modules["filterpy"], sys.modules["filterpy.stats"] = filterpy, stats
    filterpy.stats = stats


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("filterpy")
    except PackageNotFoundError:
        return "unknown"


_install_stand_ins()

from filterpy.kalman import (  # noqa: E402 - after the stand-ins above
    ExtendedKalmanFilter,
    MerweScaledSigmaPoints,
    UnscentedKalmanFilter,
    unscented_transform,
)

__all__ = ["ExtendedKalmanFilter", "MerweScaledSigmaPoints", "UnscentedKalmanFilter", "unscented_transform"]
