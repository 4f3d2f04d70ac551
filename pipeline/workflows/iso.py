"""The ``iso`` job: ISO 230-2 figures of every test. The analysis itself is
``pipeline.steps.iso``, which the ``report`` job shares.

>>> import backlash as bl
>>> result = bl.iso("ess_mcu1025_ISO230.dat")             # doctest: +SKIP
>>> result.figures[["test_id", "A", "E", "M", "R", "B"]]  # doctest: +SKIP
"""

from __future__ import annotations

from pipeline.steps.iso import PARAMETERS, iso

__all__ = ["PARAMETERS", "iso"]

# One call as the command line and as Python spell it, which tests/test_runner.py runs both
# ways and compares (the {names} are its input files and each side's own folders).
EXAMPLE = (
    ["{two}", "--machine", "M01", "--axis", "Y"],
    {"data": "{two}", "machine": "M01", "axis": "Y"},
)
