"""The ``online-id`` command line: the one place that wires core, drivers and replay together."""
