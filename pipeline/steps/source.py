"""A job's data as the user gave it: the readings, where they came from, and the selection.

``readings_of`` turns a job's data (a readings file, a fleet store or a frame) into the
validated readings frame and ``source_of`` gives the name a result calls it by: every job
reads its data through them, directly or through its ``Source``.

The runner hands a job whose record says ``source=True`` (its ``Workflow``) a ``Source``
instead of a frame it read itself: the file, store or frame as given, its format,
the test selection (``features.readings.selection``) and a raw log's reader options. The job
then reads what it needs: the selected tests (``readings``), or every machine axis
(``all_readings``) when what it says about one axis depends on the others (the fleet's wear
rate) or on the store the readings came from (its recorded compensations, voided tests, trace
days and ballbar runs). Such a job computes on the whole data and reports the axes the
selection keeps (``keeps``), so a selection never changes what is said about an axis it
keeps. A job reads a store's records (``records``) and its watchers' state (``live``) here
too: the store is opened once, each kind of record read once.

This module is light (no pandas at import): a job's module imports it at the top.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

from features.readings.errors import InputError
from features.readings.selection import Selection


def readings_of(data, format: str = "auto", parameter: str = "data", selection=None,
                options: dict | None = None, axes: bool = True):
    """The validated readings frame a job works on.

    Parameters
    ----------
    data : str, path-like or DataFrame
        A readings file (read in ``format``), a fleet store (a store folder or a
        ``postgresql://`` URL: ``pipeline.store``) or a frame as ``read`` returns it (checked,
        not re-read).
    format : str
        Layout of a readings file (``"auto"``: detect); a store takes only ``"auto"``.
    parameter : str
        The caller's parameter that passed ``data`` (named in errors).
    selection : features.readings.selection.Selection, optional
        Keep only these tests (a store reads only what it may keep).
    options : dict, optional
        Options of a raw log's reader (``channels``, ``reference_scale``: the ``camonitor``
        layout); only a file of that layout takes them.
    axes : bool, default True
        False: every machine axis within the selection's dates, the machine and axis filters
        only checked and naming a file that states none (``Selection.apply``).
    """
    selection = selection or Selection()
    if isinstance(data, (str, os.PathLike)):
        from pipeline.store import is_store, open_store

        if is_store(data) or os.path.isdir(data):
            _no_options(options, data)
            if format != "auto":
                raise InputError(f"is {format!r}, but a fleet store holds validated readings; "
                                 "expected 'auto'", parameter="format")
            store = open_store(data)
            if axes or selection.empty:
                return store.read(selection)
            # the dates read in the store (by partition or in SQL), the axes kept here
            return selection.apply(store.read(selection.dates()), store.location, axes=False)
        from features.readings.io import read_readings

        frame = read_readings(data, format, **(options or {}))
    else:
        from features.readings.validation import check_readings

        _no_options(options, parameter)
        frame = check_readings(data, parameter)
    return selection.apply(frame, frame.attrs.get("source", parameter), axes=axes)


def _no_options(options: dict | None, source) -> None:
    """A store or a frame holds readings already: a raw log's options do not apply."""
    given = [name for name, value in (options or {}).items() if value is not None]
    if given:
        raise InputError(f"applies to a raw log (--format camonitor) only; {source} holds "
                         "readings", parameter=given[0])


def source_of(data, readings) -> str:
    """The name a result gives its data: the path or store as given (a store URL without its
    password), or the frame's ``attrs["source"]``."""
    if isinstance(data, (str, os.PathLike)):
        from pipeline.store import redact

        return redact(data)
    return readings.attrs.get("source", "readings")


@dataclass
class Source:
    """The data of a job, read when asked for.

    Attributes
    ----------
    data : str, path-like or DataFrame
        A readings file, a fleet store (a folder or a ``postgresql://`` URL) or a validated
        readings frame, as given.
    format : str
        Layout of a readings file (``"auto"``: detect); a store takes only ``"auto"``.
    selection : features.readings.selection.Selection
        The tests to work on (machines, axes, dates); empty: all.
    options : dict
        A raw log's reader options (``channels``, ``reference_scale``, ``unit``), those given.
    parameter : str
        The job's parameter that passed ``data`` (named in errors).
    """

    data: object
    format: str = "auto"
    selection: Selection = field(default_factory=Selection)
    options: dict = field(default_factory=dict)
    parameter: str = "data"
    _selected: object = field(default=None, init=False, repr=False, compare=False)
    _all: object = field(default=None, init=False, repr=False, compare=False)
    _records: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    @classmethod
    def of(cls, data, format: str = "auto", parameter: str = "data") -> Source:
        """``data`` itself when it is a Source already (the runner's), else the Source of
        ``data`` without a selection (a workflow called directly)."""
        return data if isinstance(data, Source) else cls(data, format, parameter=parameter)

    def readings(self):
        """The validated readings of the tests the selection keeps (read once)."""
        if self._selected is None:
            self._selected = readings_of(self.data, self.format, self.parameter,
                                         self.selection, self.options)
        return self._selected

    def all_readings(self):
        """The validated readings of every machine axis within the selection's dates (read
        once). The machine and axis filters keep every axis here, but they still name a file
        that states none, and a selection that keeps no test is still refused."""
        if self._all is None:
            self._all = readings_of(self.data, self.format, self.parameter, self.selection,
                                    self.options, axes=False)
        return self._all

    def keeps(self, machine_id: str, axis: str) -> bool:
        """Whether the selection keeps the machine axis ``(machine_id, axis)``."""
        return self.selection.keeps(str(machine_id), str(axis))

    def kept(self, frame):
        """The rows of ``frame`` (any frame with ``machine_id`` and ``axis``) of the machine
        axes the selection keeps; ``frame`` itself when it keeps them all."""
        import numpy as np

        keep = np.ones(len(frame), dtype=bool)
        for wanted, column in ((self.selection.machine, "machine_id"),
                               (self.selection.axis, "axis")):
            if wanted is not None:
                keep &= frame[column].astype(str).isin(wanted).to_numpy()
        if keep.all():
            return frame
        out = frame[keep]
        out.attrs = dict(frame.attrs)
        return out

    @property
    def is_store(self) -> bool:
        """The data name a fleet store (a folder or a ``postgresql://`` URL)."""
        from pipeline.store import is_store

        return isinstance(self.data, (str, os.PathLike)) and is_store(self.data)

    @property
    def store(self):
        """The fleet store the readings came from (its records and voids are read there), or
        None for a file or a frame."""
        return self.data if self.is_store else None

    def records_store(self, store=None):
        """Where the records are read: ``store`` (a job's own ``store`` parameter) when given,
        else the store the readings came from; None when that names no store."""
        from pipeline.store import is_store

        where = self.store if store is None else store
        return where if isinstance(where, (str, os.PathLike)) and is_store(where) else None

    def records(self, kinds=None, store=None) -> dict:
        """The records of the fleet store ``records_store(store)`` by kind and machine axis
        (``pipeline.store.records.read_records``: {kind: {(machine_id, axis): [record, ...]}},
        oldest first): ``kinds`` of them (default every kind, and the voided tests of each
        machine axis under ``voided``, ``visit``, ``test_id``, ``at``, ``user_name``,
        ``reason``); empty without a store. The store is opened once, each kind read once."""
        from pipeline.store.tables import TABLES

        where = self.records_store(store)
        if where is None:
            return {}
        kinds = (*TABLES, "voided") if kinds is None else tuple(kinds)
        if os.fspath(where) not in self._records:
            from pipeline.store import open_store

            self._records[os.fspath(where)] = (open_store(where, parameter="store"), {})
        opened, read = self._records[os.fspath(where)]
        for kind in kinds:
            if kind not in read:
                from pipeline.store.records import read_records

                read[kind] = _voided(opened) if kind == "voided" else read_records(opened, kind)
        return {kind: read[kind] for kind in kinds}

    def live(self, store=None) -> list[dict]:
        """The watched axes of the store ``records_store(store)`` (``pipeline.store.live``:
        ``machine_id``, ``axis``, ``last_sample``, ``stale_after_s``, ``source``); none for a
        file, a frame or a PostgreSQL store (which keeps no watcher's state)."""
        where = self.records_store(store)
        if where is None or "://" in str(where):
            return []
        from pipeline.store.live import live_axes

        return live_axes(where)

    def name(self, readings=None) -> str:
        """The name a result gives its data: the path or store as given (a URL without its
        password), else the frame's ``attrs["source"]`` (of ``readings`` when given)."""
        if isinstance(self.data, (str, os.PathLike)):
            return source_of(self.data, None)
        frame = readings if readings is not None else self.data
        return frame.attrs.get("source", "readings")


def _voided(store) -> dict:
    """The voided tests of an opened store by machine axis (``Store.voids``)."""
    voids = store.voids()
    return {key: rows.drop(columns=["machine_id", "axis"]).to_dict("records")
            for key, rows in voids.groupby(["machine_id", "axis"])}
