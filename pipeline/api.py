"""The public Python API: every job of the product as a function, imported by a short name.

>>> import backlash as bl
>>> readings = bl.read("test.dat")            # doctest: +SKIP
>>> figures = bl.iso(readings).figures        # doctest: +SKIP

Each job runs through the one runner the CLI and experiment files use (``pipeline.runner``):
the same parameters with the same meaning (``machine``, ``axis``, ``since``, ``until`` select
the tests of the data in every job), ``out=`` writes the result, ``store=`` records it where
``--store`` does, ``track`` (default True, as in the CLI) logs a tracked job to MLflow; a
result object out (frames, figures, notes), nothing printed. The other names (``read``,
``load_model``, ``backtest``...) are plain functions. See ``docs/api.md``.
"""

from __future__ import annotations

import functools
import importlib

from features.readings.errors import BacklashWarning, InputError
from pipeline.workflows import WORKFLOWS, workflow

# Public names that are not jobs -> the workflow module that defines them (imported on first
# use, so that ``import backlash`` stays light). Every job is a name too, from its record.
_WHERE = {"read": "convert", "validate": "convert", "write": "convert",
          "load_model": "train", "backtest": "compare"}
_JOBS = {w.function_name or w.name.replace("-", "_"): w.name for w in WORKFLOWS}
__all__ = ["BacklashWarning", "InputError", *_WHERE, *_JOBS]  # noqa: PLE0604 (from the records)


def __getattr__(name: str):
    if name in _JOBS:
        record = workflow(_JOBS[name])
        return _through_runner(record.name, record.function)
    if name in _WHERE:
        return getattr(importlib.import_module(f"pipeline.workflows.{_WHERE[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return __all__


@functools.cache
def _through_runner(job: str, function):
    """``function``'s name, signature and docstring, run by ``pipeline.runner.run(job)``."""

    @functools.wraps(function)
    def call(*args, **params):
        from pipeline.runner import run

        return run(job, *args, **params)

    return call
