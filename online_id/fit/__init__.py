"""Batch fit: Haro's cost criterion (``cost``), the hybrid GA (``ga``) and the fit that uses them (``fit``)."""
