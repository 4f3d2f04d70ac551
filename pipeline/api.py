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

# Public name -> the workflow module that defines it (imported on first use, so that
# ``import backlash`` stays light).
_WHERE = {
    "read": "convert", "validate": "convert", "write": "convert", "convert": "convert",
    "ingest": "ingest", "check_store": "store", "void": "void",
    "iso": "iso", "report": "report", "simulate": "simulate",
    "train": "train", "load_model": "train", "predict": "predict", "compare": "compare",
    "backtest": "compare", "tune": "tune",
    "rank": "rank", "replicate": "replicate", "drift": "drift", "discover": "discover",
    "hidden_effects": "hidden_effects", "compensate": "compensate", "uncertainty": "uncertainty",
    "fleet": "fleet", "targets": "targets",
    "volumetric": "volumetric", "circle": "circle", "monitor": "monitor",
}
__all__ = [  # noqa: F822 (the jobs resolve on first use, in __getattr__)
    "BacklashWarning", "InputError", "backtest", "check_store", "circle", "compare", "compensate", "convert", "discover",
    "drift", "fleet", "hidden_effects", "ingest", "iso", "load_model", "monitor", "predict", "rank", "read", "replicate", "report",
    "simulate", "targets", "train", "tune", "uncertainty", "validate", "void", "volumetric",
    "write",
]


_JOBS = {"check_store": "store"}  # a job whose function is named otherwise


def __getattr__(name: str):
    if name in _WHERE:
        from pipeline.workflows import NAMES

        module = importlib.import_module(f"pipeline.workflows.{_WHERE[name]}")
        job = _JOBS.get(name, name.replace("_", "-"))
        function = getattr(module, name)
        return _through_runner(job, function) if job in NAMES else function
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
