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


def _map_checkout_folders() -> None:
    """From a source checkout (a clone run without an install, or a test run that imports this folder before the
    installed copy), ``online_id.drivers`` and ``online_id.replay`` are the repository's top-level ``drivers/`` and
    ``replay/`` folders, as an install maps them (pyproject.toml's package-dir; issue 37). Installed (or editable),
    they are found as usual and this finder, asked last, never answers."""
    import importlib.abc
    import importlib.util
    import sys
    from pathlib import Path

    here = Path(__file__).resolve().parent
    root = here.parent
    if not (root / "pyproject.toml").is_file():
        return
    folders = {f"online_id.{name}": root / name for name in ("drivers", "replay")
               if not (here / name).is_dir() and (root / name / "__init__.py").is_file()}
    if not folders:
        return

    class _CheckoutFolders(importlib.abc.MetaPathFinder):
        def find_spec(self, fullname, path=None, target=None):
            folder = folders.get(fullname)
            if folder is None:
                return None
            return importlib.util.spec_from_file_location(fullname, folder / "__init__.py",
                                                          submodule_search_locations=[str(folder)])

    if not any(type(f).__name__ == "_CheckoutFolders" for f in sys.meta_path):
        sys.meta_path.append(_CheckoutFolders())


_map_checkout_folders()

#: Names loaded from online_id.api on first use (PEP 562): its ``__all__`` (tests/test_api.py holds them equal).
_API = ("estimate", "fit", "diagnose", "check", "Estimate", "Fit", "Diagnosis", "Check", "Value")


def __getattr__(name: str):
    if name in _API:
        from online_id import api

        return getattr(api, name)
    raise AttributeError(f"module 'online_id' has no attribute {name!r}")


def __dir__():
    return sorted([*globals(), *_API])
