"""Which tests of a readings table to work on: one record per filter.

A fleet store holds every test of every machine axis; a command usually wants some of them.
The filters are records (``FILTERS``): the CLI declares one option per record on every
command that reads DATA (``--machine``, ``--axis``, ``--since``, ``--until``), the Python API
takes them as keyword parameters of ``read``, and ``Selection.apply`` is the one definition of
what they keep, for a store and a readings file alike. A store may select less first (by
partition or in SQL); it then applies the same ``Selection`` to what it read.

This module is light (no pandas at import): ``backlash --help`` reads ``FILTERS``.
"""

from __future__ import annotations

import datetime as dt
import re
from dataclasses import dataclass

from features.readings import schema
from features.readings.errors import InputError, note

_DATE = re.compile(r"^\d{4}-\d{2}-\d{2}$")


@dataclass(frozen=True)
class Filter:
    """One filter of the tests to read.

    Attributes
    ----------
    name : str
        The Python keyword of ``read`` and the CLI option ``--name``.
    column : str
        The readings column it looks at (``docs/data-contract.md`` section 1).
    metavar : str
        The option's value in the help text.
    help : str
        The option's help text and the docs' table.
    """

    name: str
    column: str
    metavar: str
    help: str


FILTERS: tuple[Filter, ...] = (
    Filter("machine", "machine_id", "ID[,ID...]", "only the tests of these machines"),
    Filter("axis", "axis", "AXIS[,AXIS...]",
           "only the tests of these axes (X, Y, Z, A, B, C)"),
    Filter("since", "started_at", "DATE",
           "only tests started on or after DATE (ISO 8601, e.g. 2026-01-31; UTC unless the "
           "time carries an offset)"),
    Filter("until", "started_at", "DATE",
           "only tests started on or before DATE (a date without a time includes that day)"),
)
NAMES = tuple(f.name for f in FILTERS)


@dataclass(frozen=True)
class Selection:
    """Checked filters: None where a filter was not given.

    Attributes
    ----------
    machine, axis : tuple of str or None
        Machines and axes to keep.
    since, until : pandas.Timestamp or None
        First and last start time [UTC] to keep, both inclusive, compared with a test's
        ``started_at`` (its earliest, when readings of one test differ).
    text : str
        The filters as given, for messages and the name of the selected data.
    """

    machine: tuple[str, ...] | None = None
    axis: tuple[str, ...] | None = None
    since: object = None  # pandas.Timestamp
    until: object = None  # pandas.Timestamp
    text: str = ""

    @property
    def empty(self) -> bool:
        """No filter given: every test is kept."""
        return not self.text

    def keeps(self, machine_id: str, axis: str) -> bool:
        """Whether the machine and axis filters keep the machine axis ``(machine_id, axis)``
        (the dates select its tests, not the axis)."""
        return ((self.machine is None or machine_id in self.machine)
                and (self.axis is None or axis in self.axis))

    def dates(self) -> Selection:
        """The date filters alone: every machine axis's tests within them."""
        parts = [p for p in self.text.split("; ") if p.startswith(("since ", "until "))]
        return Selection(since=self.since, until=self.until, text="; ".join(parts))

    def apply(self, readings, source: str, axes: bool = True):
        """The readings of the tests this selection keeps.

        Parameters
        ----------
        readings : DataFrame
            A validated readings frame.
        source : str
            Its name, for notes and errors; the result's ``attrs["source"]`` is
            ``"source (filters)"``.
        axes : bool, default True
            False: the machine and axis filters keep every machine axis (they still name a
            file that states none, and a selection that keeps no test is still refused); the
            dates select the tests. What a fleet-wide figure is computed on, the selected
            axes being picked from it afterwards (``keeps``).

        Raises
        ------
        InputError
            No test is left (naming ``source`` and what it holds).
        """
        if self.empty:
            _note_taken(readings, source)
            return readings
        readings, named = self._name_unstated(readings, source)
        times = self._times(readings, source)
        keep = self._labels(readings, skip=named) & times
        if not keep.any():
            raise InputError(f"no test matches {self.text}; {_holdings(readings)}", file=source)
        if not axes:
            keep = times
        out = (readings.copy(deep=False) if keep.all()
               else readings[keep].reset_index(drop=True))
        out.attrs["source"] = f"{source} ({self.text})"
        return out

    def _name_unstated(self, readings, source):
        """A file that states no machine or axis (``schema.UNSTATED``) gets the one given:
        ``--axis Y`` on an ecmc file names its axis Y rather than selecting nothing. A linear
        file cannot be named a rotary axis nor the reverse: its deviations are in um, a
        rotary axis's in arcsec."""
        unstated = readings.attrs.get(schema.UNSTATED, ())
        named = []
        for name in ("machine", "axis"):
            wanted, column = getattr(self, name), _column(name)
            if wanted is None or column not in unstated:
                continue
            if len(wanted) != 1:
                raise InputError(f"the file states no {name}; expected one --{name} to name "
                                 f"it, got {', '.join(wanted)}", file=source, parameter=name)
            if name == "axis":
                _check_same_kind(readings["axis"], wanted[0], source)
            namer = readings.attrs.get(schema.NAMED_BY, {}).get(column)
            said = (f"{namer} names {name} {', '.join(map(str, readings[column].unique()))}"
                    if namer else f"the file states no {name}")
            if not named:
                readings = readings.copy(deep=False)
            readings[column] = wanted[0]
            named.append(name)
            note(f"{source}: {said}; named {wanted[0]} (--{name})")
        if "axis" not in named:
            _note_taken(readings, source)
        if named:
            readings.attrs[schema.UNSTATED] = tuple(
                c for c in unstated if c not in map(_column, named))
        return readings, tuple(named)

    def _labels(self, readings, skip=()):
        import numpy as np

        keep = np.ones(len(readings), dtype=bool)
        for name in ("machine", "axis"):
            wanted = getattr(self, name)
            if wanted is not None and name not in skip:
                keep &= readings[_column(name)].isin(wanted).to_numpy()
        return keep

    def _times(self, readings, source):
        import numpy as np

        if self.since is None and self.until is None:
            return np.ones(len(readings), dtype=bool)
        if "started_at" not in readings:
            raise InputError(f"no started_at column: {self.text} cannot select tests by date",
                             file=source)
        started = readings.groupby(list(schema.TEST_KEYS), sort=False)["started_at"] \
            .transform("min")
        undated = started.isna()
        if undated.any():
            tests = readings.loc[undated, list(schema.TEST_KEYS)].drop_duplicates()
            note(f"{source}: {len(tests)} tests without started_at left out by {self.text}")
        keep = ~undated
        if self.since is not None:
            keep &= started >= self.since
        if self.until is not None:
            keep &= started <= self.until
        return keep.to_numpy()


def _note_taken(readings, source) -> None:
    """Note the axis a reader took for a file that names none, when no ``--axis`` named it
    (an ecmc file whose set-point PV names no axis letter: X, or A when its UNIT is deg)."""
    if "axis" in readings.attrs.get(schema.UNSTATED, ()) and "axis" not in readings.attrs.get(
            schema.NAMED_BY, {}):
        axes = ", ".join(map(str, readings["axis"].unique()))
        note(f"{source}: the file states no axis; taken as {axes} (name it with --axis)")


def _check_same_kind(axes, named: str, source) -> None:
    rotary = set(axes.unique()) <= set(schema.ROTARY_AXES)
    if rotary != (named in schema.ROTARY_AXES):
        have = "a rotary axis (deviations in arcsec)" if rotary else \
            "a linear axis (deviations in um)"
        raise InputError(f"the file holds {have}; --axis {named} is "
                         f"{'rotary' if named in schema.ROTARY_AXES else 'linear'}",
                         file=source, parameter="axis")


def selection(machine=None, axis=None, since=None, until=None) -> Selection:
    """Check the filters of ``read`` and return them as a ``Selection``.

    Parameters
    ----------
    machine : str or list of str, optional
        Machine ids to keep (a str is one id).
    axis : str or list of str, optional
        Axis names to keep (X, Y, Z, A, B, C; any case).
    since, until : str, datetime.date, datetime.datetime or pandas.Timestamp, optional
        First and last day or instant of ``started_at`` to keep (inclusive; a date without a
        time is the whole day; times without an offset are UTC).

    Raises
    ------
    InputError
        A filter that cannot select anything, naming its parameter.
    """
    machines = _labels_of(machine, "machine")
    axes = _labels_of(axis, "axis")
    if axes is not None:
        axes = tuple(a.upper() for a in axes)
        known = schema.LINEAR_AXES + schema.ROTARY_AXES
        unknown = [a for a in axes if a not in known]
        if unknown:
            raise InputError(f"unknown axis {unknown[0]!r}; expected {', '.join(known)}",
                             parameter="axis")
    first, last = _instant(since, "since", end=False), _instant(until, "until", end=True)
    if first is not None and last is not None and first > last:
        raise InputError(f"since {since} is after until {until}; expected since <= until",
                         parameter="since")
    parts = [f"{n} {', '.join(v)}" for n, v in (("machine", machines), ("axis", axes)) if v]
    parts += [f"{n} {v}" for n, v in (("since", since), ("until", until)) if v is not None]
    return Selection(machines, axes, first, last, "; ".join(parts))


def _column(name: str) -> str:
    return next(f.column for f in FILTERS if f.name == name)


def _labels_of(value, parameter: str) -> tuple[str, ...] | None:
    if value is None:
        return None
    values = [value] if isinstance(value, str) else value
    if not isinstance(values, (list, tuple)) or not all(isinstance(v, str) for v in values):
        raise InputError(f"must be a str or a list of str; got {value!r}", parameter=parameter)
    values = [v.strip() for v in values]
    if not values or not all(values):
        raise InputError("is empty; expected one or more names", parameter=parameter)
    return tuple(dict.fromkeys(values))


def _instant(value, parameter: str, end: bool):
    """``value`` as a UTC Timestamp; a date alone is its first (``end``: last) microsecond."""
    import pandas as pd

    if value is None:
        return None
    whole_day = (isinstance(value, dt.date) and not isinstance(value, dt.datetime)) or (
        isinstance(value, str) and _DATE.match(value.strip()))
    try:
        if not isinstance(value, (str, dt.date)):
            raise TypeError
        stamp = pd.Timestamp(value.strip() if isinstance(value, str) else value)
    except (TypeError, ValueError):
        raise InputError(f"{value!r} is not an ISO 8601 date or date-time (e.g. 2026-01-31)",
                         parameter=parameter) from None
    if stamp is pd.NaT:
        raise InputError(f"{value!r} is not a date", parameter=parameter)
    stamp = stamp.tz_localize("UTC") if stamp.tzinfo is None else stamp.tz_convert("UTC")
    if whole_day and end:
        stamp += pd.Timedelta(days=1) - pd.Timedelta(microseconds=1)
    return stamp


def _holdings(readings) -> str:
    """What the data hold, for the "no test matches" error."""
    machines = sorted(readings["machine_id"].unique())
    axes = sorted(readings["axis"].unique())
    shown = ", ".join(machines[:5]) + (" ..." if len(machines) > 5 else "")
    return f"the data hold machines {shown} and axes {', '.join(axes)}"
