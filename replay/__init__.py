"""Real-time replay of logged track runs and CAN logs onto a CAN bus.

Depends on the core (``online_id``) and on ``drivers``; the core never imports this package.
"""
