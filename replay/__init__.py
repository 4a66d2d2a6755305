"""Real-time replay of logged track runs and CAN logs onto a CAN bus.

Installed as ``online_id.replay`` (the folder stays at the top of the repository); the name ``replay`` is
deprecated (issue 37). Depends on the core and on ``online_id.drivers``; the core never imports this package.
``player.play`` paces any frame sequence; pacing is a wrapper around a source, not a feature of one.
"""

if __name__ == "replay":  # the old top-level name, found as this folder from a checkout: as the installed shim does
    from online_id._moved import alias_moved_package

    alias_moved_package(__name__, "online_id.replay")
