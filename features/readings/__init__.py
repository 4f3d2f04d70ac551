"""The readings contract, the ground floor every other layer stands on: column names and
units (``schema``), the one user-error type (``errors``), the accepted input layouts
(``formats``), validation at the edge (``validation``) and atomic output (``fileio``).
See ``docs/data-contract.md``."""

from features.readings.io import read_readings, write_readings

__all__ = ["read_readings", "write_readings"]
