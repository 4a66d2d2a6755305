"""Batch fit: Haro's cost criterion (``cost``), the hybrid GA (``ga``) and the fit that uses them (``fit``).

The package is also callable: ``online_id.fit(source, ...)`` is :func:`online_id.api.fit` (the notebook
API's name meets this package's; once any ``online_id.fit.*`` module is imported, ``online_id.fit`` is this
package, so the package itself forwards the call).
"""

import sys
import types


class _CallableModule(types.ModuleType):
    def __call__(self, *args, **kwargs):
        from online_id.api import fit

        return fit(*args, **kwargs)


sys.modules[__name__].__class__ = _CallableModule
