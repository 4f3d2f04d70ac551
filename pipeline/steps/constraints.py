"""The jobs' tables' constraints, declared in scikit-learn's language
(``sklearn.utils._param_validation``) without importing scikit-learn.

``Interval``, ``Options``, ``StrOptions`` and ``HasMethods`` take the arguments of
scikit-learn's classes of the same names (``Interval(Integral, 1, None, closed="left")``,
``StrOptions(("a", "b"))``) and only hold them: every job module builds its ``PARAMETERS`` at
import, and ``backlash CMD --help`` imports the job module, so a table must import nothing
heavy (scikit-learn brings numpy, scipy and pandas: a second or more). The command line reads
what it needs from a declaration (an ``Options``'s choices, in order; an ``Interval``'s number
type), and ``sklearn()`` builds scikit-learn's own object, imported then.

The runner's ``check_params`` converts a table's declarations (``resolved``) and leaves
the decision to scikit-learn's ``validate_parameter_constraints``; nothing here decides
whether a value meets a constraint. Options given as a tuple keep its order (in scikit-learn's
message and in the command line's choices); a set's are sorted.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field

__all__ = ["HasMethods", "Interval", "Options", "StrOptions", "resolved", "takes_bool"]

_SKLEARN = "sklearn.utils._param_validation"


class Declaration:
    """A constraint of a table, as scikit-learn's class of the same name takes it."""

    def sklearn(self):
        """scikit-learn's own constraint object (scikit-learn imported now)."""
        raise NotImplementedError

    def __str__(self) -> str:
        """scikit-learn's words for it (``"an int in the range [1, inf)"``)."""
        return str(self.sklearn())


@dataclass(frozen=True)
class Interval(Declaration):
    """scikit-learn's ``Interval(type, left, right, *, closed)``: a number of ``type``
    (``Integral`` or ``Real``) between ``left`` and ``right`` (None: unbounded)."""

    type: type
    left: object
    right: object
    closed: str = field(kw_only=True)

    def sklearn(self):
        from sklearn.utils._param_validation import Interval

        return Interval(self.type, self.left, self.right, closed=self.closed)


@dataclass(frozen=True, init=False)
class Options(Declaration):
    """scikit-learn's ``Options(type, options, *, deprecated=None)``: one of ``options`` (a
    tuple keeps its order; a set's are sorted), each an instance of ``type``."""

    type: type
    options: tuple
    deprecated: frozenset

    def __init__(self, type, options, *, deprecated=None):
        ordered = (tuple(sorted(options, key=repr)) if isinstance(options, (set, frozenset))
                   else tuple(options))
        object.__setattr__(self, "type", type)
        object.__setattr__(self, "options", ordered)
        object.__setattr__(self, "deprecated", frozenset(deprecated or ()))

    def sklearn(self):
        from sklearn.utils import _param_validation as sk

        return self._ordered(sk.Options(self.type, frozenset(self.options),
                                        deprecated=set(self.deprecated) or None))

    def _ordered(self, made):
        # scikit-learn's constructor takes a set (it checks that the deprecated options are
        # among them); its checks and its words only iterate and test membership, so its
        # object keeps the options in their declared order
        made.options = self.options
        return made


@dataclass(frozen=True, init=False)
class StrOptions(Options):
    """scikit-learn's ``StrOptions(options, *, deprecated=None)``: one of the strings
    ``options`` (a tuple keeps its order; a set's are sorted)."""

    def __init__(self, options, *, deprecated=None):
        super().__init__(str, options, deprecated=deprecated)

    def sklearn(self):
        from sklearn.utils import _param_validation as sk

        return self._ordered(sk.StrOptions(frozenset(self.options),
                                           deprecated=set(self.deprecated) or None))


@dataclass(frozen=True, init=False)
class HasMethods(Declaration):
    """scikit-learn's ``HasMethods(methods)``: an object with these methods (a name or a list
    of names)."""

    methods: tuple

    def __init__(self, methods):
        object.__setattr__(self, "methods", (methods,) if isinstance(methods, str)
                           else tuple(methods))

    def sklearn(self):
        from sklearn.utils._param_validation import HasMethods

        return HasMethods(list(self.methods))


def resolved(constraints) -> list:
    """``constraints`` as scikit-learn takes them: each declaration as scikit-learn's own
    object, a type a table names by its dotted path (``"pandas.DataFrame"``, so that the table
    imports no heavy module) imported; anything else (a type, None, ``"boolean"``, a
    scikit-learn object) as it is."""
    import importlib

    def one(c):
        if isinstance(c, Declaration):
            return c.sklearn()
        if isinstance(c, str) and "." in c:  # scikit-learn's own names have no dot
            module, _, name = c.rpartition(".")
            return getattr(importlib.import_module(module), name)
        return c

    return [one(c) for c in constraints]


def takes_bool(constraints) -> bool:
    """Whether a parameter takes true or false as such: ``"boolean"``, ``bool``, or options
    holding one (declared, or scikit-learn's own when a table gives its object)."""
    sk = sys.modules.get(_SKLEARN)  # an object of scikit-learn's means it is imported

    def options(c) -> tuple:
        if isinstance(c, Options) or sk is not None and isinstance(c, sk.Options):
            return tuple(c.options)
        return ()

    return any((isinstance(c, str) and c == "boolean") or c is bool
               or any(isinstance(o, bool) for o in options(c)) for c in constraints)
