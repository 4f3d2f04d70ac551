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

from features.readings.errors import BacklashWarning, InputError  # noqa: F401 (public names)
from pipeline import workflows

# Public names that are not jobs -> the workflow module that defines them (imported on first
# use, so that ``import backlash`` stays light). Every job is a name too, from its record.
_WHERE = {"read": "convert", "validate": "convert", "write": "convert",
          "load_model": "train", "backtest": "compare"}


def jobs() -> dict[str, str]:
    """Python name -> job, from the job records as they are now (``pipeline.workflows``; a job
    added by ``register`` has its name)."""
    return {w.function_name or w.name.replace("-", "_"): w.name for w in workflows.WORKFLOWS}


def __getattr__(name: str):
    if name == "__all__":  # read from the records, not frozen at import
        return ["BacklashWarning", "InputError", *_WHERE, *jobs()]
    names = jobs()
    if name in names:
        record = workflows.workflow(names[name])
        return _through_runner(record.name, record.function)
    if name in _WHERE:
        return getattr(importlib.import_module(f"pipeline.workflows.{_WHERE[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return __getattr__("__all__")


def jobs_table() -> str:
    """The docs' table of the jobs' Python names (``docs/api.md``, filled in by
    ``docs/hooks.py`` as the site is built): per job its name, what it does (its record's
    summary), what it returns (its function's annotation) and its page."""
    import inspect

    rows = ["| function | does | returns |", "|---|---|---|"]
    for name, job in jobs().items():
        record = workflows.workflow(job)
        returns = inspect.signature(record.function).return_annotation
        shown = ("" if returns is inspect.Signature.empty
                 else f"`{getattr(returns, '__name__', returns)}`")
        summary = record.summary.replace("|", "/")
        rows.append(f"| `bl.{name}` | {summary} [more]({job}.md) | {shown} |")
    return "\n".join(rows) + "\n"


@functools.cache
def _through_runner(job: str, function):
    """``function``'s name, signature and docstring, run by ``pipeline.runner.run(job)``."""

    @functools.wraps(function)
    def call(*args, **params):
        from pipeline.runner import run

        return run(job, *args, **params)

    return call
