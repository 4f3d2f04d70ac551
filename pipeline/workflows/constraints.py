"""scikit-learn's parameter constraints, without importing scikit-learn.

``Interval``, ``Options``, ``StrOptions`` and ``HasMethods`` take the arguments the workflows
give scikit-learn's (``sklearn.utils._param_validation``), accept the same values and describe
themselves in the same words, so ``pipeline.workflows.check_params`` words its errors alike
whichever declared a parameter. A workflow that fits no estimator declares its parameters with
these: importing scikit-learn's constraints pulls in scikit-learn, scipy.sparse and
scipy.stats, about a second of a command that otherwise needs none of them.
"""

from __future__ import annotations

import math
import operator
from numbers import Integral, Real

CLOSED = ("left", "right", "both", "neither")


class _Constraint:
    """A set of accepted values: ``is_satisfied_by(value)`` and ``str()`` (for the error)."""

    def is_satisfied_by(self, value) -> bool:
        raise NotImplementedError


class Interval(_Constraint):
    """Numbers of ``type`` (``numbers.Integral`` or ``numbers.Real``) between ``left`` and
    ``right`` (None: unbounded), ``closed`` on 'left', 'right', 'both' or 'neither' side."""

    def __init__(self, type, left, right, *, closed: str):
        if type not in (Integral, Real):
            raise ValueError(f"type must be either numbers.Integral or numbers.Real. Got {type} "
                             "instead.")
        if closed not in CLOSED:
            raise ValueError(f"closed must be either 'left', 'right', 'both' or 'neither'. "
                             f"Got {closed} instead.")
        if left is not None and right is not None and right <= left:
            raise ValueError(f"right can't be less than left. Got left={left} and "
                             f"right={right}")
        self.type, self.left, self.right, self.closed = type, left, right, closed

    def is_satisfied_by(self, value) -> bool:
        if not isinstance(value, self.type):
            return False
        if not isinstance(value, Integral) and math.isnan(value):
            return False
        below = operator.lt if self.closed in ("left", "both") else operator.le
        above = operator.gt if self.closed in ("right", "both") else operator.ge
        left = -math.inf if self.left is None else self.left
        right = math.inf if self.right is None else self.right
        return not below(value, left) and not above(value, right)

    def __str__(self) -> str:
        left = "-inf" if self.left is None else self.left
        right = "inf" if self.right is None else self.right
        if self.type is not Integral:  # scikit-learn shows a float's bounds as floats
            left = float(left) if isinstance(self.left, Real) else left
            right = float(right) if isinstance(self.right, Real) else right
        return (f"{'an int' if self.type is Integral else 'a float'} in the range "
                f"{'[' if self.closed in ('left', 'both') else '('}{left}, "
                f"{right}{']' if self.closed in ('right', 'both') else ')'}")


class Options(_Constraint):
    """One of the values in ``options`` (a set, or a tuple to keep their order in messages
    and in the command line's choices), each an instance of ``type``."""

    def __init__(self, type, options):
        self.type, self.options = type, options

    def is_satisfied_by(self, value) -> bool:
        return isinstance(value, self.type) and value in self.options

    def __str__(self) -> str:
        listed = ", ".join(repr(o) for o in self.options)
        return f"a {_type_name(self.type)} among {{{listed}}}"


class StrOptions(Options):
    """One of the strings in the set ``options``."""

    def __init__(self, options):
        super().__init__(str, options)


class HasMethods(_Constraint):
    """Any object with the callable attribute(s) ``methods`` (a name or a list of names)."""

    def __init__(self, methods):
        self.methods = [methods] if isinstance(methods, str) else list(methods)

    def is_satisfied_by(self, value) -> bool:
        return all(callable(getattr(value, m, None)) for m in self.methods)

    def __str__(self) -> str:
        names = [repr(m) for m in self.methods]
        listed = names[0] if len(names) == 1 else f"{', '.join(names[:-1])} and {names[-1]}"
        return f"an object implementing {listed}"


class _InstanceOf(_Constraint):
    def __init__(self, type):
        self.type = type

    def is_satisfied_by(self, value) -> bool:
        return isinstance(value, self.type)

    def __str__(self) -> str:
        return f"an instance of {_type_name(self.type)!r}"


class _Boolean(_Constraint):
    """scikit-learn's "boolean": a Python or a numpy bool."""

    def is_satisfied_by(self, value) -> bool:
        import numpy as np

        return isinstance(value, (bool, np.bool_))

    def __str__(self) -> str:
        return "an instance of 'bool' or an instance of 'numpy.bool'"


class _ArrayLike(_Constraint):
    """scikit-learn's "array-like": a sized or array-convertible value that is not a scalar."""

    def is_satisfied_by(self, value) -> bool:
        import numpy as np

        return (hasattr(value, "__len__") or hasattr(value, "shape")
                or hasattr(value, "__array__")) and not np.isscalar(value)

    def __str__(self) -> str:
        return "an array-like"


class _Dotted(_InstanceOf):
    """An instance of a type named by its dotted path (``"pandas.DataFrame"``), imported only
    when a value is checked: a parameter table stays light."""

    def __init__(self, path: str):
        self.path = path

    @property
    def type(self):
        import importlib

        module, _, name = self.path.rpartition(".")
        return getattr(importlib.import_module(module), name)

    def __str__(self) -> str:
        return f"an instance of {self.path!r}"


class _Callable(_Constraint):
    """scikit-learn's ``callable``: a function or any object that can be called."""

    def is_satisfied_by(self, value) -> bool:
        return callable(value)

    def __str__(self) -> str:
        return "a callable"


NAMED = {"boolean": _Boolean, "array-like": _ArrayLike}


class _IsNone(_Constraint):
    def is_satisfied_by(self, value) -> bool:
        return value is None

    def __str__(self) -> str:
        return "None"


def _type_name(t: type) -> str:
    if t.__module__ == "builtins":
        return t.__qualname__
    if t is Real:
        return "float"
    if t is Integral:
        return "int"
    return f"{t.__module__}.{t.__qualname__}"


def understood(constraints: list) -> bool:
    """Whether this module checks every constraint of a parameter: its own classes, types,
    None, "boolean" and "array-like" (anything else, such as scikit-learn's classes, goes to
    scikit-learn)."""
    return all(c is None or c is callable or isinstance(c, (type, _Constraint)) or c in NAMED
               or _dotted(c)
               for c in constraints)


def _dotted(c) -> bool:
    return isinstance(c, str) and "." in c


def violation(constraints: list, value, name: str, caller: str) -> str | None:
    """None when ``value`` meets one of ``constraints``; else scikit-learn's message, "The
    'name' parameter of caller must be A, B or C. Got value instead."."""
    checks = [_constraint(c) for c in constraints]
    if any(c.is_satisfied_by(value) for c in checks):
        return None
    return must_be(constraints, value, name, caller)


def must_be(constraints: list, value, name: str, caller: str) -> str:
    """scikit-learn's wording of ``value`` breaking ``constraints`` (theirs or these)."""
    texts = [c if isinstance(c, str) and c not in NAMED and not _dotted(c) else str(_constraint(c))
             for c in constraints]  # scikit-learn's other names ("random_state") as written
    listed = texts[0] if len(texts) == 1 else f"{', '.join(texts[:-1])} or {texts[-1]}"
    return f"The {name!r} parameter of {caller} must be {listed}. Got {value!r} instead."


def takes_bool(constraints: list) -> bool:
    """Whether a parameter takes true or false as such. Python's ``True`` is also the int 1,
    so an ``Interval`` or an ``int`` type alone would take it: a flag written where a number
    belongs (``seed = true``) would run as 1."""
    return any(c == "boolean" or c is bool or isinstance(c, _Boolean)
               or (isinstance(c, Options) and any(isinstance(o, bool) for o in c.options))
               for c in constraints)


def _constraint(c) -> _Constraint:
    if c is None:
        return _IsNone()
    if c is callable:
        return _Callable()
    if isinstance(c, type):
        return _InstanceOf(c)
    if _dotted(c):
        return _Dotted(c)
    if isinstance(c, str):
        return NAMED[c]()
    return c
