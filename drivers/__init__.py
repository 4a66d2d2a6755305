"""Sensor sources: track-run CSV, CAN log files and live CAN buses, all yielding the same samples.

Installed as ``online_id.drivers`` (the folder stays at the top of the repository); the name ``drivers`` is
deprecated (issue 37). Depends on the core; the core's models and filters never import this package.

* ``base.SampleSource``: the one interface (iterate for samples; ``report()``, ``problems()``, ``ended_by``)
* ``csv_source.TrackRunSource``, ``can_log.CanLogSource``, ``can_bus.CanBusSource``: the sources
* ``signal_map``: TOML maps from a car's DBC signals to canonical names and SI units
* ``assembler``: multi-rate frames to samples (latest value, staleness, per-ID accounting)
* ``frames``: online-id's own frames (``data/online_id.dbc``)

A new bus interface needs nothing here when python-can has it (pass its name); a new file
format likewise, when python-can's LogReader reads it. A new kind of source subclasses
``SampleSource``.
"""

if __name__ == "drivers":  # the old top-level name, found as this folder from a checkout: as the installed shim does
    from online_id._moved import alias_moved_package

    alias_moved_package(__name__, "online_id.drivers")
