"""The batch fit over a whole run: Haro's cost criterion (``cost``), the hybrid GA (``ga``), the fit that
uses them (``fit``) and the Gauss-Newton polish of an online estimate (``polish``).

(``online_id.fit(...)``, the notebook function, is :func:`online_id.api.fit`; this package is named apart
from it.)
"""
