"""Vehicles: known constants, the 8 estimated parameters with names and units, TOML loading."""

from online_id.vehicle.loader import Vehicle, builtin_vehicle_names, load_vehicle, parse_vehicle
from online_id.vehicle.parameters import PARAMETER_NAMES, PARAMETER_UNITS, KnownParameters, Parameters

__all__ = ["PARAMETER_NAMES", "PARAMETER_UNITS", "KnownParameters", "Parameters", "Vehicle",
           "builtin_vehicle_names", "load_vehicle", "parse_vehicle"]
