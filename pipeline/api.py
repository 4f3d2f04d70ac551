"""The public Python API: every job of the product as a function, imported by a short name.

>>> import backlash as bl
>>> readings = bl.read("test.dat")            # doctest: +SKIP
>>> figures = bl.iso(readings).figures        # doctest: +SKIP

Each function is the workflow the CLI and experiment files call (``pipeline.workflows``):
keyword parameters checked on entry, a result object out (frames, figures, notes), nothing
printed. See ``docs/api.md``.
"""

from __future__ import annotations

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


def __getattr__(name: str):
    if name in _WHERE:
        module = importlib.import_module(f"pipeline.workflows.{_WHERE[name]}")
        return getattr(module, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return __all__
