"""Configuration files as typed data: one reader from TOML into dataclasses.

Twin campaigns, experiment files and discovery scenarios are TOML files (or dicts of the same
shape) read by ``read_config`` into the dataclasses that describe them. The dataclass is the
schema: its fields are the allowed keys, their annotations the allowed values, their defaults
the values of keys left out. A key the dataclass does not know, or a value of the wrong kind,
is one ``InputError`` naming the file and the key's dotted path (``fleet.visits``), which the
CLI prints as one line with exit code 2.

Supported annotations: ``bool``, ``int`` (whole numbers; ``3.0`` is read as ``3``), ``float``
(finite; an integer is kept as written), ``str``, ``Literal["a", "b"]``, ``list[X]``,
``dict[str, X]`` (a table of tables with free keys), ``dict`` (a free table), ``datetime.date``
(a TOML date, ``2026-03-01``, or the same as text), ``X | None`` and nested dataclasses. Checks of meaning (a positive duration, a known name) belong to the
dataclass's ``check(where)`` method, called after the types are read.
"""

from __future__ import annotations

import copy
import dataclasses
import datetime as dt
import math
import types
import typing
from collections.abc import Mapping

from features.readings.errors import InputError


def read_config(source, cls, *, base=None, what: str = "configuration", file=None):
    """A dataclass instance from a TOML file or a dict of the same shape.

    Parameters
    ----------
    source : str, Path or dict
        The TOML file, or its content as a dict.
    cls : type
        The dataclass describing the file.
    base : cls, optional
        Values for the keys the source leaves out (default: the fields' defaults). Nested
        dataclasses are merged key by key; other tables (``dict`` fields) are replaced whole.
    what : str
        What the file is, for the message when it cannot be read ("experiment").
    file : str, optional
        The name to give in messages when ``source`` is a dict.

    Returns
    -------
    cls
        The typed configuration; ``cls.check(file)`` has run if the class defines it.

    Raises
    ------
    InputError
        The first unknown key, value of the wrong kind or missing key, naming the file and the
        key's dotted path (``column``).
    """
    from features.readings.fileio import read_toml

    if isinstance(source, Mapping):
        table = source
    else:
        table, file = read_toml(source, what), str(source)
    return from_table(table, cls, base=base, file=file)


def from_table(table, cls, *, base=None, file=None, prefix: str = ""):
    """``cls`` from a table whose keys lie below ``prefix`` (``"plan."``) in the file."""
    if not isinstance(table, Mapping):
        raise InputError(f"expected a table, got {table!r}", file=file,
                         column=prefix.rstrip(".") or None)
    hints = typing.get_type_hints(cls)
    # the file's key of each field: its name, or metadata["key"] where the key is no Python
    # name (``with``)
    fields = {f.metadata.get("key", f.name): f for f in dataclasses.fields(cls) if f.init}
    unknown = [key for key in table if key not in fields]
    if unknown:
        raise InputError(f"unknown key {prefix + str(unknown[0])!r}; expected "
                         f"{', '.join(fields)}", file=file, column=prefix + str(unknown[0]))
    values = {}
    for name, field in fields.items():
        key = prefix + name
        if name in table:
            inner = getattr(base, field.name, None) if base is not None else None
            values[field.name] = _value(table[name], hints[field.name], key, file, inner)
        elif base is not None:
            values[field.name] = copy.deepcopy(getattr(base, field.name))
        elif (field.default is dataclasses.MISSING
              and field.default_factory is dataclasses.MISSING):
            raise InputError(f"missing key {key!r}", file=file, column=key)
    out = cls(**values)
    if hasattr(out, "check"):
        out.check(file)
    return out


def as_table(obj) -> dict:
    """A dataclass as the plain table it was read from (keys in field order)."""
    return dataclasses.asdict(obj)


# --------------------------------------------------------------------------- values
def _value(value, kind, key: str, file, base=None):
    """``value`` checked against annotation ``kind`` (and converted where lossless)."""
    origin, args = typing.get_origin(kind), typing.get_args(kind)
    if origin in (typing.Union, types.UnionType):
        options = [a for a in args if a is not type(None)]
        if value is None and len(options) < len(args):
            return None
        for option in options[1:]:  # the first kind that takes the value; else the first's error
            try:
                return _value(value, option, key, file, base)
            except InputError:
                pass
        return _value(value, options[0], key, file, base)
    if dataclasses.is_dataclass(kind):
        return from_table(value, kind, base=base, file=file, prefix=key + ".")
    if origin is typing.Literal:
        if all(isinstance(a, str) for a in args) and not isinstance(value, str):
            _bad("text", value, key, file)
        if value not in args:
            raise InputError(f"expected one of {', '.join(map(str, args))}, got {value!r}",
                             file=file, column=key)
        return value
    if origin is list:
        item = args[0] if args else typing.Any
        if not isinstance(value, list) or not all(_fits(v, item) for v in value):
            _bad(f"a list of {_plural(item)}", value, key, file)
        # a table in a list of tables is named by its place: special[2].name
        return [_value(v, item, f"{key}[{i}]" if dataclasses.is_dataclass(item) else key, file)
                for i, v in enumerate(value, start=1)]
    if origin is dict or kind is dict:
        if not isinstance(value, Mapping):
            _bad("a table", value, key, file)
        if not args:
            return copy.deepcopy(dict(value))
        return {k: _value(v, args[1], f"{key}.{k}", file) for k, v in value.items()}
    if kind is typing.Any:
        return copy.deepcopy(value)
    if not _fits(value, kind):
        _bad(_name(kind), value, key, file)
    if kind is dt.date and isinstance(value, str):
        return dt.date.fromisoformat(value)
    return int(value) if kind is int else value


def _fits(value, kind) -> bool:
    if kind is dt.date:  # a day, not a moment: a TOML date-time is refused
        if isinstance(value, str):
            try:
                dt.date.fromisoformat(value)
            except ValueError:
                return False
            return len(value) == 10
        return isinstance(value, dt.date) and not isinstance(value, dt.datetime)
    if kind is bool:
        return isinstance(value, bool)
    if kind in (int, float):
        ok = (isinstance(value, (int, float)) and not isinstance(value, bool)
              and math.isfinite(value))
        return ok and (kind is float or value == int(value))
    if kind is str:
        return isinstance(value, str)
    if typing.get_origin(kind) is typing.Literal:
        return value in typing.get_args(kind)
    return True  # tables and nested lists are checked by ``_value``


def _name(kind) -> str:
    return {bool: "true or false", int: "a whole number", float: "a number (finite)",
            str: "text", dt.date: "a date (YYYY-MM-DD)"}.get(kind, "a value")


def _plural(kind) -> str:
    if dataclasses.is_dataclass(kind):
        return "tables"
    return {bool: "true or false", int: "whole numbers", float: "numbers (finite)",
            str: "text"}.get(kind, "values")


def _bad(expected: str, value, key: str, file) -> typing.NoReturn:
    if expected == "a whole number" and not _fits(value, float):
        expected = "a number (finite, whole)"
    raise InputError(f"expected {expected}, got {value!r}", file=file, column=key)

