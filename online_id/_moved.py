"""The old top-level names of packages that moved into ``online_id`` (issue 37), kept for one release.

``drivers`` and ``replay`` were installed as top-level packages, names any other distribution may take; they are
``online_id.drivers`` and ``online_id.replay`` now. ``import drivers`` (and ``import drivers.sources``, ``from
replay.player import play``) still work, with a :class:`DeprecationWarning`, and give the very same module objects
as the new names: no module is loaded twice, so a class is the same class under either name.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
import warnings


class _MovedFinder(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Finds ``old.sub`` as the already importable ``new.sub`` (the module itself, not a second copy)."""

    def __init__(self, old: str, new: str):
        self.old, self.new = old, new

    def find_spec(self, fullname, path=None, target=None):
        if fullname.startswith(self.old + "."):
            return importlib.util.spec_from_loader(fullname, self)
        return None

    def create_module(self, spec):
        return importlib.import_module(self.new + spec.name[len(self.old):])

    def exec_module(self, module) -> None:
        pass  # the module ran under its new name


def alias_moved_package(old: str, new: str) -> None:
    """Make ``old`` (being imported) and its submodules the modules of ``new``, with a DeprecationWarning."""
    warnings.warn(f"'{old}' is now '{new}': the name '{old}' goes in the next release", DeprecationWarning,
                  stacklevel=3)  # the importing line: 1 is here, 2 the package's __init__ (importlib's frames skipped)
    sys.modules[old] = importlib.import_module(new)
    if not any(isinstance(f, _MovedFinder) and f.old == old for f in sys.meta_path):
        sys.meta_path.insert(0, _MovedFinder(old, new))
