"""Sensor sources: track-run CSV, CAN log files and live CAN buses, all yielding the same samples.

Depends on the core (``online_id``); the core never imports this package.

* ``base.SampleSource``: the one interface (iterate for samples; ``report()``, ``problems()``, ``ended_by``)
* ``csv_source.TrackRunSource``, ``can_log.CanLogSource``, ``can_bus.CanBusSource``: the sources
* ``signal_map``: TOML maps from a car's DBC signals to canonical names and SI units
* ``assembler``: multi-rate frames to samples (latest value, staleness, per-ID accounting)
* ``frames``: online-id's own frames (``data/online_id.dbc``)

A new bus interface needs nothing here when python-can has it (pass its name); a new file
format likewise, when python-can's LogReader reads it. A new kind of source subclasses
``SampleSource``.
"""
