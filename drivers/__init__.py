"""Sensor sources: track-run CSV, CAN log files and live CAN buses, all yielding the same samples.

Depends on the core (``online_id``); the core never imports this package.
"""
