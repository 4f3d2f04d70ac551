"""scikit-learn's parameter constraints (``sklearn.utils._param_validation``), as the jobs'
tables write them.

``Interval`` and ``HasMethods`` are scikit-learn's own; ``Options`` and ``StrOptions`` are
scikit-learn's, also taking a tuple of options (scikit-learn takes a set), whose order is then
kept in the error and in the command line's choices. ``pipeline.workflows.check_params``
checks values against them with scikit-learn's ``validate_parameter_constraints``.
"""

from __future__ import annotations

from sklearn.utils import _param_validation as _sk
from sklearn.utils._param_validation import HasMethods, Interval

__all__ = ["HasMethods", "Interval", "Options", "StrOptions", "resolved", "takes_bool"]


class Options(_sk.Options):
    """scikit-learn's ``Options``: one of ``options`` (a set, or a tuple to keep their order),
    each an instance of ``type``."""

    def __init__(self, type, options, *, deprecated=None):
        super().__init__(type, frozenset(options), deprecated=deprecated)
        self.options = options


class StrOptions(_sk.StrOptions):
    """scikit-learn's ``StrOptions``: one of the strings ``options`` (a set, or a tuple to keep
    their order)."""

    def __init__(self, options, *, deprecated=None):
        super().__init__(frozenset(options), deprecated=deprecated)
        self.options = options


def resolved(constraints) -> list:
    """``constraints`` as scikit-learn takes them: a type a table names by its dotted path
    (``"pandas.DataFrame"``, so that the table imports no heavy module) imported."""
    import importlib

    def one(c):
        if isinstance(c, str) and "." in c:  # scikit-learn's own names have no dot
            module, _, name = c.rpartition(".")
            return getattr(importlib.import_module(module), name)
        return c

    return [one(c) for c in constraints]


def takes_bool(constraints) -> bool:
    """Whether a parameter takes true or false as such. Python's ``True`` is also the int 1,
    so an ``Interval`` or an ``int`` type alone would take it: a flag written where a number
    belongs (``seed = true``) would run as 1."""
    return any(c == "boolean" or c is bool
               or (isinstance(c, _sk.Options) and any(isinstance(o, bool) for o in c.options))
               for c in constraints)
