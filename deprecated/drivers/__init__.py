"""Deprecated: ``drivers`` is ``online_id.drivers`` (issue 37). Installed for one release so that
``import drivers`` still works, with a DeprecationWarning; removed in the next."""

from online_id._moved import alias_moved_package

alias_moved_package(__name__, "online_id.drivers")
