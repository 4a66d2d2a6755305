"""Real-time replay of logged track runs and CAN logs onto a CAN bus.

Depends on the core (``online_id``) and on ``drivers``; the core never imports this package.
``player.play`` paces any frame sequence; pacing is a wrapper around a source, not a feature of one.
"""
