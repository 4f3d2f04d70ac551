"""The ``iso`` job: ISO 230-2 figures of every test. The analysis itself is
``pipeline.steps.iso``, which the ``report`` job shares.

>>> import backlash as bl
>>> result = bl.iso("ess_mcu1025_ISO230.dat")             # doctest: +SKIP
>>> result.figures[["test_id", "A", "E", "M", "R", "B"]]  # doctest: +SKIP
"""

from __future__ import annotations

from pipeline.steps.iso import PARAMETERS, iso

__all__ = ["PARAMETERS", "iso"]
