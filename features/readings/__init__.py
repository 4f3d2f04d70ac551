"""The readings contract, the ground floor every other layer stands on: column names and
units (``schema``), the one user-error type and notes (``errors``), one record per accepted
input layout (``layouts``) and their readers (``formats``, ``rtl``), validation at the edge
(``validation``) and atomic output (``fileio``).
See ``docs/data-contract.md``."""

__all__ = ["read_readings", "write_readings"]


def __getattr__(name):
    """``read_readings``/``write_readings`` on first use: importing the contract's light parts
    (schema, errors) must not import pandas, so ``backlash --help`` stays fast."""
    if name in __all__:
        from features.readings import io

        return getattr(io, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
