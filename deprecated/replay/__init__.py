"""Deprecated: ``replay`` is ``online_id.replay`` (issue 37). Installed for one release so that
``import replay`` still works, with a DeprecationWarning; removed in the next."""

from online_id._moved import alias_moved_package

alias_moved_package(__name__, "online_id.replay")
